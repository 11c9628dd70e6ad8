"""
Unquoted string values in ``--hyperparams`` (and the zoo's other ``key:value`` options): ``sb3_offon.cli_args``.

Parsing only, with one exception: the command line run in this process up to the model's creation (no training).
"""

import argparse
import sys
from pathlib import Path
from typing import Any

import pytest
import rl_zoo3.enjoy as zoo_enjoy
import rl_zoo3.train as zoo_train
import yaml
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.utils import StoreDict
from torch import nn

from sb3_offon import OffOnDQN
from sb3_offon.cli_args import STRING_OPTIONS, TolerantStoreDict, use_tolerant_store_dict
from sb3_offon.train import main as train_main
from sb3_offon.zoo import OffOnExperimentManager


def parse(*pairs: str, action: type[argparse.Action] = TolerantStoreDict) -> dict[str, Any]:
    """``--hyperparams pairs...`` through ``action``, declared as the zoo's ``train`` declares it."""
    parser = argparse.ArgumentParser()
    parser.add_argument("-params", "--hyperparams", type=str, nargs="+", action=action)
    return parser.parse_args(["--hyperparams", *pairs]).hyperparams


def test_bare_words_are_strings() -> None:
    assert parse("mc_mixing:convex", "sarsa_target:expected", "policy:MlpPolicy", "device:cpu", "loss: mse") == {
        "mc_mixing": "convex",
        "sarsa_target": "expected",
        "policy": "MlpPolicy",
        "device": "cpu",
        "loss": "mse",
    }


def test_zoo_alone_fails_on_bare_words() -> None:
    # What this module fixes (if the zoo ever parses them itself, TolerantStoreDict can go)
    with pytest.raises(NameError, match="convex"):
        parse("mc_mixing:convex", action=StoreDict)


@pytest.mark.parametrize("key", sorted(STRING_OPTIONS))
def test_every_string_option(key: str) -> None:
    # "max" included: evaluated, it would be Python's builtin max; "lambda" too: a keyword, which eval cannot take alone
    for option in STRING_OPTIONS[key]:
        assert parse(f"{key}:{option}") == {key: option}


# Values the zoo evaluates (each line as it reaches the program, after the shell's quotes), and their meaning
EVALUATED = {
    "learning_rate:1e-3": 1e-3,
    "batch_size:64": 64,
    "n_timesteps:-1": -1,
    "policy_kwargs:dict(net_arch=[64])": {"net_arch": [64]},
    "policy_kwargs:dict(net_arch=[64], activation_fn=nn.ReLU)": {"net_arch": [64], "activation_fn": nn.ReLU},
    "mc_mixing:'convex'": "convex",
    'sarsa_target:"expected"': "expected",
    "learning_rate:'lin_1e-3'": "lin_1e-3",
    "train_freq:(4, 'step')": (4, "step"),
    "env_wrapper:[{'gymnasium.wrappers.TimeLimit': {'max_episode_steps': 10}}]": [
        {"gymnasium.wrappers.TimeLimit": {"max_episode_steps": 10}}
    ],
    "normalize:True": True,
    "target_kl:None": None,
    "url:'a:b'": "a:b",
    # Names the zoo's namespace defines keep their meaning: torch there, Python's builtins for other keys than ours
    "activation_fn:nn": nn,
    "any_key:max": max,
}


@pytest.mark.parametrize("pair", EVALUATED)
def test_evaluated_values_keep_the_zoo_meaning(pair: str) -> None:
    key = pair.partition(":")[0]
    assert parse(pair) == parse(pair, action=StoreDict) == {key: EVALUATED[pair]}


@pytest.mark.parametrize(
    ("pair", "error"),
    [
        # Not a single name: the zoo's error, as before (a schedule needs its quotes, "learning_rate:'lin_1e-3'")
        ("learning_rate:lin_1e-3", NameError),
        ("policy_kwargs:dict(net_arch=[unknown])", NameError),
        ("batch_size:64 +", SyntaxError),
    ],
)
def test_other_failures_unchanged(pair: str, error: type[Exception]) -> None:
    for action in (TolerantStoreDict, StoreDict):
        with pytest.raises(error):
            parse(pair, action=action)


def test_use_tolerant_store_dict(monkeypatch: pytest.MonkeyPatch) -> None:
    for module in (zoo_train, zoo_enjoy):
        # Restored after the test
        monkeypatch.setattr(module, "StoreDict", module.StoreDict)
    use_tolerant_store_dict()
    assert zoo_train.StoreDict is TolerantStoreDict
    assert zoo_enjoy.StoreDict is TolerantStoreDict
    assert issubclass(TolerantStoreDict, StoreDict)


def test_command_line_reaches_the_model(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``python -m sb3_offon.train ... --hyperparams mc_mixing:convex ...`` in this process, stopped before training."""
    for module in (zoo_train, zoo_enjoy):
        monkeypatch.setattr(module, "StoreDict", module.StoreDict)
    models = []
    # The command line's manager trains in a learn of its own (sb3_offon.zoo.OffOnExperimentManager)
    monkeypatch.setattr(OffOnExperimentManager, "learn", lambda self, model: models.append(model))
    monkeypatch.setattr(ExperimentManager, "save_trained_model", lambda self, model: None)
    monkeypatch.chdir(tmp_path)
    command = ["sb3_offon.train", "--algo", "offon_dqn", "--env", "CartPole-v1", "-n", "100", "-f", "logs"]
    command += ["--seed", "0", "--eval-freq", "-1", "--num-threads", "1", "--hyperparams"]
    command += ["mc_mixing:convex", "sarsa_target:expected", "learning_rate:1e-3", "policy_kwargs:dict(net_arch=[64])"]
    monkeypatch.setattr(sys, "argv", command)
    train_main()

    (model,) = models
    assert isinstance(model, OffOnDQN)
    assert (model.mc_mixing, model.sarsa_target) == ("convex", "expected")
    # The zoo turns a float learning rate into a constant schedule
    assert model.lr_schedule(1.0) == 1e-3
    assert model.policy_kwargs["net_arch"] == [64]
    run = tmp_path / "logs" / "offon_dqn" / "CartPole-v1_1" / "CartPole-v1"
    config = dict(yaml.load((run / "config.yml").read_text(), Loader=yaml.UnsafeLoader))
    assert (config["mc_mixing"], config["sarsa_target"]) == ("convex", "expected")
    args = yaml.load((run / "args.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert dict(args)["hyperparams"]["mc_mixing"] == "convex"
