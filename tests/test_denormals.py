"""
Denormal floats flushed to zero (the command line's default, ``sb3_offon.train.flush_denormals_unless_kept``): the mode
is set unless ``--keep-denormals``, and training from an optimizer state holding denormals gives the same parameters
with and without it; ``scripts/bench_denormals.py`` compares the two from a checkpoint.
"""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch as th
from helpers import SCRIPTS, load_script
from stable_baselines3 import DQN

from sb3_offon import OffOnDQN
from sb3_offon.qrdqn import QRDQN
from sb3_offon.train import flush_denormals_unless_kept

DENORMAL = 1e-39
# scripts/bench_denormals.py's count of an optimizer state's denormal entries
BENCH_DENORMALS = load_script("bench_denormals")


def flushes() -> bool:
    """Whether this thread flushes denormals now: a denormal input then reads as zero."""
    return bool((th.tensor([DENORMAL]) * 2.0).item() == 0.0)


def denormal_count(model: DQN) -> int:
    """Entries of the optimizer's running averages strictly between 0 and the smallest normal float."""
    return BENCH_DENORMALS.denormal_entries(model)[0]


def test_the_command_line_flushes_unless_told_to_keep_them() -> None:
    # conftest.py's ieee_denormals fixture starts every test with IEEE arithmetic
    assert not flushes()
    assert flush_denormals_unless_kept(["--algo", "dqn", "--keep-denormals"]) is False
    assert not flushes(), "--keep-denormals leaves IEEE arithmetic"
    if not flush_denormals_unless_kept(["--algo", "dqn"]):
        pytest.skip("this CPU has no flush-to-zero mode")
    assert flushes()


def trained_with_denormals(algo: type[DQN], flush: bool) -> DQN:
    """
    A model trained a little on CartPole-v1 with centred RMSprop (the MinAtar settings' optimizer), then with a third of
    its optimizer's running averages made denormal (as the state of weights whose gradients stay zero decays into),
    then trained 50 more gradient steps with or without flushing.
    """
    model = algo(
        "MlpPolicy",
        "CartPole-v1",
        learning_starts=200,
        train_freq=1,
        target_update_interval=50,
        policy_kwargs=dict(
            net_arch=[32], optimizer_class=th.optim.RMSprop, optimizer_kwargs=dict(alpha=0.95, eps=0.01, centered=True)
        ),
        seed=0,
        device="cpu",
    )
    model.learn(400)
    generator = th.Generator().manual_seed(0)
    for state in model.policy.optimizer.state.values():
        chosen = th.rand(state["square_avg"].shape, generator=generator) < 1 / 3
        # Both averages of a weight, so that the variance estimate square_avg - grad_avg**2 stays >= 0
        state["square_avg"][chosen] = DENORMAL
        state["grad_avg"][chosen] = DENORMAL * th.where(state["grad_avg"][chosen] < 0, -1.0, 1.0)
    assert denormal_count(model) > 100
    th.set_flush_denormal(flush)
    np.random.seed(1)
    th.manual_seed(1)
    model.train(gradient_steps=50, batch_size=32)
    th.set_flush_denormal(False)
    return model


@pytest.mark.parametrize("algo", [OffOnDQN, DQN, QRDQN])
def test_flushing_leaves_the_parameters_as_they_are(algo: type[DQN]) -> None:
    if not th.set_flush_denormal(False):
        pytest.skip("this CPU has no flush-to-zero mode")
    kept = trained_with_denormals(algo, flush=False)
    flushed = trained_with_denormals(algo, flush=True)
    assert denormal_count(kept) > 0 and denormal_count(flushed) == 0, "the arithmetic did differ"
    flushed_parameters = flushed.policy.state_dict()
    for name, kept_parameter in kept.policy.state_dict().items():
        assert th.equal(kept_parameter, flushed_parameters[name]), name


@pytest.mark.slow
def test_the_benchmark_compares_both_arithmetics_from_a_checkpoint(tmp_path) -> None:
    # scripts/bench_denormals.py on a checkpoint laid out as benchmark.py keeps them (<run>/<step>/); no speed asserted
    model = trained_with_denormals(DQN, flush=False)
    checkpoint = tmp_path / "CartPole-v1_0" / "400"
    checkpoint.mkdir(parents=True)
    model.save(checkpoint / "model.zip")
    model.save_replay_buffer(checkpoint / "replay_buffer.pkl")
    (checkpoint / "checkpoint.json").write_text(json.dumps({"num_timesteps": 400}))
    arguments = ["--algo", "dqn", "--gradient-steps", "20", "--pairs", "2", "--output", str(tmp_path / "out")]
    finished = subprocess.run(
        [sys.executable, str(SCRIPTS / "bench_denormals.py"), str(checkpoint), *arguments],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert finished.returncode == 0, finished.stderr[-3000:]
    record = json.loads((tmp_path / "out" / "denormals_dqn_CartPole-v1_0_400.json").read_text())
    assert record["run"] == "CartPole-v1_0" and record["num_timesteps"] == 400
    assert 0 < record["denormal_share_of_optimizer_state"] < 1
    assert [row["ieee_first"] for row in record["rows"]] == [True, False], "the pairs take turns"
    assert record["parameters_identical"] is True
    assert "bit-identical" in (tmp_path / "out" / "denormals_dqn_CartPole-v1_0_400.md").read_text()
