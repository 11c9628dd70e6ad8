"""
``scripts/bench_speed.py``: the two runs of a pair take turns, and each learns exactly what it would learn alone;
``scripts/bench_qrdqn_loss.py`` writes its tables.

No speed is asserted here (that is the benchmark's job); only that taking turns does not change what is measured,
and that each run's timers nest (its training time is part of its learn() time).
"""

import hashlib
import json
import subprocess
import sys

import numpy as np
import pytest
from helpers import SCRIPTS, load_script
from stable_baselines3 import DQN

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.qrdqn import QRDQN

HYPERPARAMS = dict(
    learning_starts=100, train_freq=16, gradient_steps=8, batch_size=32, buffer_size=1000, policy_kwargs=dict(net_arch=[16])
)
TIMESTEPS = 600


def parameters_digest(model) -> str:
    return hashlib.sha1(b"".join(p.detach().numpy().tobytes() for p in model.policy.parameters())).hexdigest()


@pytest.mark.parametrize(
    "extra_kwargs, classes",
    [
        (None, None),
        ({"DQN": {"n_steps": 10}, "OffOnDQN": {"mc_mixing": "sample", "mc_initial_prob": 0.9, "mc_final_prob": 0.9}}, None),
        # An option of OffOnDQN against its defaults: both runs are OffOnDQN
        ({"OffOnDQN": {"double_q": True}}, {"DQN": OffOnDQN}),
        # The QR-DQN family: OffOnQRDQN against the package's QR-DQN
        (
            {
                "DQN": {"policy_kwargs": dict(net_arch=[16], n_quantiles=5)},
                "OffOnDQN": {"policy_kwargs": dict(net_arch=[16], n_quantiles=5)},
            },
            {"DQN": QRDQN, "OffOnDQN": OffOnQRDQN},
        ),
        # OffOnDQN's defaults against n-step QR-DQN (--baseline qrdqn_nstep): the baseline's n-step buffer in turns
        (
            {"DQN": {"n_steps": 3, "policy_kwargs": dict(net_arch=[16], n_quantiles=5)}},
            {"DQN": QRDQN, "OffOnDQN": OffOnDQN},
        ),
    ],
    ids=["dqn-defaults", "nstep-coin-flips", "offon-double-q", "qrdqn-family", "nstep-qrdqn-baseline"],
)
def test_runs_taking_turns_learn_what_they_learn_alone(monkeypatch, extra_kwargs, classes):
    bench_speed = load_script("bench_speed")
    # Keep each pair's models, to compare them with runs made alone
    built = []
    original_build = bench_speed.build

    def keep(*args, **kwargs):
        model_and_train_seconds = original_build(*args, **kwargs)
        built.append(model_and_train_seconds[0])
        return model_and_train_seconds

    monkeypatch.setattr(bench_speed, "build", keep)
    # Hand over every 50 steps: a dozen turns each, in the middle of rollouts and of training bursts
    runs = bench_speed.run_pair(
        ("DQN", "OffOnDQN"), "CartPole-v1", HYPERPARAMS, TIMESTEPS, 3, 50, extra_kwargs=extra_kwargs, classes=classes
    )

    assert [type(model) for model in built] == [(classes or {}).get("DQN", DQN), (classes or {}).get("OffOnDQN", OffOnDQN)]
    for role, model in zip(("DQN", "OffOnDQN"), built, strict=True):
        own = (extra_kwargs or {}).get(role, {})
        alone = type(model)("MlpPolicy", "CartPole-v1", seed=3, device="cpu", **{**HYPERPARAMS, **own}).learn(TIMESTEPS)
        for key, value in own.items():
            if key != "policy_kwargs":
                assert getattr(model, key) == value, key
        assert parameters_digest(model) == parameters_digest(alone), role
        run = runs[role]
        assert run["class"] == type(model).__name__
        assert run["env_steps"] == alone.num_timesteps
        assert run["episodes"] == len(alone.env.env_method("get_episode_lengths")[0])
        # Each run is timed only while it holds the baton: both times are parts of the pair's elapsed time
        assert 0 < run["train_seconds"] < run["learn_seconds"]
        assert np.isfinite(run["steps_per_second"])


def test_baton_alternates_and_lets_the_survivor_run_on():
    bench_speed = load_script("bench_speed")
    baton = bench_speed.Baton("a", "b")
    assert baton.holder == "a"
    baton.hand_over("a")
    assert baton.holder == "b"
    baton.hand_over("b", finished=True)
    assert baton.holder == "a"
    baton.hand_over("a")
    assert baton.holder == "a", "the other run has finished: nobody to wait for"


@pytest.mark.parametrize("name", ["cartpole", "lambda_lunarlander", "lambda_lunarlander_vs_nstep"])
def test_tables_say_which_baseline_the_dqn_columns_are(name):
    """The tables' "DQN" columns are n-step DQN's with ``--baseline dqn_nstep``: the table says so, and only then."""
    module = load_script("bench_speed")
    result = json.loads((SCRIPTS.parent / "results" / "speed" / f"{name}.json").read_text())
    table = module.markdown_table(result)
    said = "The DQN columns and rows are the baseline's: SB3's DQN with n_steps=10 (n-step DQN)." in table.splitlines()
    assert said == (result.get("baseline", "dqn") == "dqn_nstep")
    assert table.splitlines()[4 if said else 2].startswith("| pair | order | DQN steps/s |")


def test_the_candidates_own_arguments_are_parsed_and_shown_in_the_table():
    """``--hyperparams`` takes a study file's ``key:value`` items as the training command line does, refuses a setting
    both runs share, and the table names the candidate's arguments."""
    module = load_script("bench_speed")
    items = ["mc_initial_prob:0.670", "n_steps:3", "lambda_form:projected", "lambda_cache:False", "mc_mixing:lambda"]
    args = module.parse_args(["--hyperparams", *items])
    expected = {
        "mc_initial_prob": 0.67,
        "n_steps": 3,
        "lambda_form": "projected",
        "lambda_cache": False,
        "mc_mixing": "lambda",
    }
    assert args.hyperparams == expected
    assert module.parse_args([]).hyperparams == {}
    shared = module.ZOO_HYPERPARAMS["MinAtar/Breakout-v0"]
    assert module.candidate_arguments("projected", {"mc_initial_prob": 0.67}, shared) == {
        "lambda_form": "projected",
        "mc_initial_prob": 0.67,
    }
    with pytest.raises(SystemExit, match="--hyperparams: batch_size, train_freq is a setting both runs share"):
        module.candidate_arguments("defaults", {"train_freq": 1, "batch_size": 8}, shared)
    result = json.loads((SCRIPTS.parent / "results" / "speed" / "cartpole.json").read_text())
    plain = module.markdown_table(result).splitlines()[0]
    result["candidate_hyperparams"] = {"mc_initial_prob": 0.67, "lambda_form": "projected"}
    named = module.markdown_table(result).splitlines()[0]
    assert "mc_initial_prob=0.67 lambda_form='projected'," in named
    assert named.replace(" mc_initial_prob=0.67 lambda_form='projected'", "") == plain


def test_every_baseline_is_named_in_the_tables():
    """A baseline added to ``--baseline`` gets a name for its tables' "DQN" columns, and the name says its class."""
    bench_speed = load_script("bench_speed")
    speed_report = load_script("speed_report")
    assert set(speed_report.BASELINE_NAMES) == set(bench_speed.BASELINES)
    for baseline, (baseline_class, kwargs) in bench_speed.BASELINES.items():
        name = speed_report.BASELINE_NAMES[baseline]
        assert ("DQN" in name) if baseline_class.__name__ == "DQN" else (baseline_class.__name__ in name), baseline
        assert all(f"{key}={value}" in name for key, value in kwargs.items()), baseline


@pytest.mark.slow
def test_the_qrdqn_loss_benchmark_writes_its_table(tmp_path):
    pytest.importorskip("minatar", reason="the 'minatar' extra is not installed")  # it times MinAtar/Breakout-v0
    # A tiny run of scripts/bench_qrdqn_loss.py (no speed asserted): both classes timed, the loss alone too
    output = tmp_path / "qrdqn.json"
    tiny = ["--repeats", "2", "--timesteps", "200", "--prefill", "100", "--loss-rounds", "1", "--output", str(output)]
    command = [sys.executable, str(SCRIPTS / "bench_qrdqn_loss.py"), *tiny]
    finished = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert finished.returncode == 0, finished.stderr[-3000:]
    result = json.loads(output.read_text())
    assert len(result["loss_ms"]["sb3-contrib"]) == len(result["loss_ms"]["sb3_offon"]) == 1
    assert [pair["starts"] for pair in result["pairs"]] == ["sb3-contrib QRDQN", "sb3_offon QRDQN"]
    for pair in result["pairs"]:
        assert pair["sb3-contrib QRDQN"]["class"] == pair["sb3_offon QRDQN"]["class"] == "QRDQN"
        assert pair["sb3-contrib QRDQN"]["env_steps"] == pair["sb3_offon QRDQN"]["env_steps"] == 200
    assert len(result["wall"]["pair_ratios"]) == 2
    assert "| **median** |" in output.with_suffix(".md").read_text()
