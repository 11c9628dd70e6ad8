"""OffOnDQN's defaults (the search's lambda-return choice), the paper's preset, and the ablations that keep the paper's."""

import inspect

import pytest
import yaml

from sb3_offon import DQNMC, LAMBDA_CHOICE_TARGETS, PAPER_TARGETS, DQNSarsa, OffOnDQN
from sb3_offon.zoo import HYPERPARAMS_DIR


def defaults_of(algo: type) -> dict:
    return {name: p.default for name, p in inspect.signature(algo.__init__).parameters.items() if p.default is not p.empty}


def yaml_entries(name: str) -> dict:
    with open(HYPERPARAMS_DIR / f"{name}.yml") as file:
        return yaml.safe_load(file)


def test_offon_dqn_defaults_are_the_lambda_choice():
    defaults = defaults_of(OffOnDQN)
    assert {key: defaults[key] for key in LAMBDA_CHOICE_TARGETS} == dict(LAMBDA_CHOICE_TARGETS)
    model = OffOnDQN("MlpPolicy", "CartPole-v1")
    assert (model.mc_mixing, model.mc_initial_prob, model.mc_final_prob) == ("lambda", 0.9, 0.9)
    assert (model.qlearning_initial_prob, model.qlearning_final_prob) == (0.0, 0.0)


@pytest.mark.parametrize("preset, algo", [(LAMBDA_CHOICE_TARGETS, "offon_dqn"), (PAPER_TARGETS, "offon_paper")])
def test_presets_are_what_the_command_line_trains(preset, algo):
    """Every entry of the algorithm's YAML file writes out the preset's values (so the defaults cannot leak in)."""
    # A schedule's fraction matters only where it moves (offon_dqn.yml leaves qlearning_fraction out: 0 -> 0)
    needed = {
        key: value
        for key, value in preset.items()
        if not key.endswith("_fraction")
        or preset[key.replace("fraction", "initial_prob")] != preset[key.replace("fraction", "final_prob")]
    }
    for env_id, entry in yaml_entries(algo).items():
        assert {key: entry.get(key) for key in needed} == needed, (algo, env_id)


def test_paper_preset_gives_the_papers_coin_flips():
    model = OffOnDQN("MlpPolicy", "CartPole-v1", **PAPER_TARGETS)
    assert (model.mc_mixing, model.mc_initial_prob, model.mc_final_prob) == ("sample", 0.99, 0.01)
    assert (model.qlearning_initial_prob, model.qlearning_final_prob) == (0.99, 0.01)
    changed = OffOnDQN("MlpPolicy", "CartPole-v1", **{**PAPER_TARGETS, "mc_final_prob": 0.1})
    assert (changed.mc_mixing, changed.mc_final_prob) == ("sample", 0.1)
    with pytest.raises(TypeError):
        PAPER_TARGETS["mc_final_prob"] = 0.5  # type: ignore[index]


def test_ablations_keep_the_papers_targets():
    dqn_mc = DQNMC("MlpPolicy", "CartPole-v1")
    assert (dqn_mc.mc_mixing, dqn_mc.mc_initial_prob, dqn_mc.mc_final_prob) == ("sample", 0.99, 0.01)
    assert (dqn_mc.qlearning_initial_prob, dqn_mc.qlearning_final_prob) == (1.0, 1.0)
    dqn_sarsa = DQNSarsa("MlpPolicy", "CartPole-v1")
    assert (dqn_sarsa.mc_mixing, dqn_sarsa.mc_initial_prob, dqn_sarsa.mc_final_prob) == ("sample", 0.0, 0.0)
    assert (dqn_sarsa.qlearning_initial_prob, dqn_sarsa.qlearning_final_prob) == (0.99, 0.01)
