"""
SIGTERM under the command line (:mod:`sb3_offon.termination`) and under the benchmark runner: a run in training stops
at its next rollout start with a checkpoint of that step, elsewhere where the signal lands; both exit with status 143,
and the command they print, or the runner run again, goes on from the checkpoint. The signals are real ones
(``os.kill`` of this process, or of a runner subprocess), sent from inside training where the step must be known.
"""

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import SCRIPTS, run_train
from stable_baselines3.common.monitor import load_results

import sb3_offon.zoo
from sb3_offon import OffOnDQN
from sb3_offon.resume import Checkpoint, RunCheckpoint, checkpoint_problem
from sb3_offon.termination import TERMINATED, TERMINATION, Terminated, sigterm_stops_the_run, termination_deferred

PROG = "python -m sb3_offon.train"
# Learning from step 100, a training call of 2 gradient steps every 50 env steps: rollout starts at every multiple of 50
SHORT = ["--eval-freq", "-1", "--seed", "0", "--hyperparams", "learning_starts:100", "train_freq:50", "gradient_steps:2"]
RUN = ["--algo", "offon_dqn", "--env", "CartPole-v1", "-n", "400", "-f", "logs"]


def sigterm_in_training_at(monkeypatch: pytest.MonkeyPatch, step: int) -> None:
    """A real SIGTERM to this process inside OffOnDQN's first training call at or after ``step``."""
    train = OffOnDQN.train
    sent: list[int] = []

    def train_with_a_sigterm(self: OffOnDQN, *args: object, **kwargs: object) -> None:
        if self.num_timesteps >= step and not sent:
            sent.append(self.num_timesteps)
            os.kill(os.getpid(), signal.SIGTERM)
        train(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(OffOnDQN, "train", train_with_a_sigterm)


def last_line(capsys: pytest.CaptureFixture) -> str:
    return capsys.readouterr().err.strip().splitlines()[-1]


def go_on(line: str) -> list[str]:
    """The arguments of the command the line gives to go on (without the program)."""
    command = shlex.split(line.partition("to go on from it: ")[2])
    assert command[:3] == shlex.split(PROG)
    return command[3:]


def test_sigterm_in_training_stops_at_the_next_rollout_with_a_checkpoint_of_that_step(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)
    handler = signal.getsignal(signal.SIGTERM)
    command = [*RUN, "--checkpoint-freq", "200", "--checkpoint-dir", "ckpt", *SHORT]
    with monkeypatch.context() as patch:
        # In the training call of step 250, after the checkpoint of step 200: the run finishes the call, then stops
        sigterm_in_training_at(patch, 250)
        assert run_train(patch, *command) == TERMINATED == 143
    line = last_line(capsys)
    assert line.startswith(f"{PROG}: stopped (SIGTERM) at step 250 of 400; newest checkpoint: step 250 in ckpt; to go on")
    checkpoint = Checkpoint.latest("ckpt")
    assert checkpoint is not None and checkpoint.num_timesteps == 250 and checkpoint_problem(checkpoint.folder) is None
    assert (checkpoint.folder / "replay_buffer.pkl").is_file()
    # The gradient steps of that call were taken before the checkpoint: the model is the one the run had at 250
    assert OffOnDQN.load(checkpoint.folder / "model.zip")._n_updates == 2 * len(range(150, 251, 50))
    assert signal.getsignal(signal.SIGTERM) is handler and not TERMINATION.installed
    # The zoo saved the model trained so far, and the command given goes on to the budget
    assert OffOnDQN.load(tmp_path / "logs" / "offon_dqn" / "CartPole-v1_1" / "CartPole-v1.zip").num_timesteps == 250
    assert run_train(monkeypatch, *go_on(line)) == 0
    assert OffOnDQN.load(tmp_path / "logs" / "offon_dqn" / "CartPole-v1_2" / "CartPole-v1.zip").num_timesteps == 400


def test_sigterm_without_checkpoints_stops_where_it_lands(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    sigterm_in_training_at(monkeypatch, 250)
    assert run_train(monkeypatch, *RUN, *SHORT) == TERMINATED
    assert last_line(capsys) == (
        f"{PROG}: stopped (SIGTERM) at step 250 of 400, without checkpoints (--checkpoint-freq STEPS writes them): no "
        "checkpoint to resume from; the model trained so far is saved in logs/offon_dqn/CartPole-v1_1"
    )
    # Stopped inside the training call: its gradient steps were not all taken
    model = OffOnDQN.load(tmp_path / "logs" / "offon_dqn" / "CartPole-v1_1" / "CartPole-v1.zip")
    assert model.num_timesteps == 250 and model._n_updates == 2 * len(range(150, 201, 50))


def test_a_run_cut_in_its_evaluation_after_training_resumes_at_its_budget(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)
    final_evaluation = sb3_offon.zoo.final_evaluation
    played: list[int] = []

    def final_evaluation_cut(model, *args, **kwargs):  # type: ignore[no-untyped-def]
        played.append(model.num_timesteps)
        if len(played) == 1:
            os.kill(os.getpid(), signal.SIGTERM)  # in the games, outside training: the run stops there
        return final_evaluation(model, *args, **kwargs)

    monkeypatch.setattr(sb3_offon.zoo, "final_evaluation", final_evaluation_cut)
    command = [*RUN, "--checkpoint-freq", "300", "--checkpoint-dir", "ckpt", *SHORT, "final_eval_episodes:3"]
    assert run_train(monkeypatch, *command) == TERMINATED
    line = last_line(capsys)
    assert line.startswith(
        f"{PROG}: stopped (SIGTERM) while the run was set up, evaluated after training or saved; newest checkpoint: step "
        "400 in ckpt; to go on from it: "
    )
    # The trained model was checkpointed before the games (not only the checkpoint of step 300)
    checkpoint = Checkpoint.latest("ckpt")
    assert checkpoint is not None and checkpoint.num_timesteps == 400
    # Resumed, it trains no further and plays the games; its monitor file holds the training episodes of the first part
    assert run_train(monkeypatch, *go_on(line)) == 0
    assert played == [400, 400]
    resumed = tmp_path / "logs" / "offon_dqn" / "CartPole-v1_2"
    with np.load(resumed / "final_evaluation.npz") as record:
        assert len(record["results"]) == 3
    first = tmp_path / "logs" / "offon_dqn" / "CartPole-v1_1"
    assert load_results(str(resumed))["l"].sum() == load_results(str(first))["l"].sum() > 300
    assert OffOnDQN.load(resumed / "CartPole-v1.zip").num_timesteps == 400
    assert not (tmp_path / "ckpt").exists()  # finished: its checkpoints removed


def test_a_sigterm_in_the_last_rollout_stops_with_a_checkpoint_of_the_budget(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    # In the training call of step 400 of 400: no rollout start follows, training ends, and the run stops there
    monkeypatch.chdir(tmp_path)
    played: list[int] = []
    final_evaluation = sb3_offon.zoo.final_evaluation
    monkeypatch.setattr(
        sb3_offon.zoo, "final_evaluation", lambda model, *a, **k: played.append(0) or final_evaluation(model, *a, **k)
    )
    command = [*RUN, "--checkpoint-freq", "300", "--checkpoint-dir", "ckpt", *SHORT, "final_eval_episodes:2"]
    with monkeypatch.context() as patch:
        sigterm_in_training_at(patch, 400)
        assert run_train(patch, *command) == TERMINATED
    line = last_line(capsys)
    assert line.startswith(f"{PROG}: stopped (SIGTERM) at step 400 of 400; newest checkpoint: step 400 in ckpt; to go on")
    assert played == []  # stopped before the games
    assert run_train(monkeypatch, *go_on(line)) == 0 and played == [0]
    assert not (tmp_path / "ckpt").exists()


def test_a_sigterm_while_a_checkpoint_is_written_takes_effect_once_it_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Outside a deferring block SIGTERM stops where it lands, but not inside torch's zip writer (see interrupts_held)."""
    model = OffOnDQN("MlpPolicy", "CartPole-v1", learning_starts=200, train_freq=4, buffer_size=5000, seed=5)
    original_save = OffOnDQN.save

    def save_with_a_sigterm(self, path, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        if self.num_timesteps == 1000:
            os.kill(os.getpid(), signal.SIGTERM)  # delivered now, in the middle of the checkpoint
        original_save(self, path, *args, **kwargs)

    monkeypatch.setattr(OffOnDQN, "save", save_with_a_sigterm)
    with sigterm_stops_the_run(), pytest.raises(Terminated):
        model.learn(2000, callback=RunCheckpoint(tmp_path, 500))
    checkpoint = Checkpoint.latest(tmp_path)
    assert checkpoint is not None and checkpoint.num_timesteps == 1000 and checkpoint_problem(checkpoint.folder) is None
    assert model.num_timesteps == 1000


def test_a_sigterm_before_a_deferring_block_is_taken_at_once() -> None:
    with sigterm_stops_the_run():
        TERMINATION.deferred = True  # as inside a run's training: the signal is only noted
        os.kill(os.getpid(), signal.SIGTERM)
        assert TERMINATION.pending
        TERMINATION.deferred = False
        with pytest.raises(Terminated), termination_deferred():
            pytest.fail("the block must not start")  # pragma: no cover
    assert not TERMINATION.pending  # outside the command line, nothing is pending


@pytest.mark.slow
def test_sigterm_stops_the_runner_and_the_same_command_resumes_its_run(tmp_path: Path) -> None:
    root = tmp_path / "raw"
    # Two runs on one worker, long enough to be running when the signal comes; the runner alone gets it
    command = [sys.executable, str(SCRIPTS / "benchmark.py"), "--set", "paper", "--algos", "dqn", "--envs", "CartPole-v1"]
    command += ["--seeds", "0", "1", "-n", "1000000", "--eval-freq", "500", "--eval-episodes", "2", "--workers", "1"]
    command += ["--root", str(root)]
    checkpoints = root / ".checkpoints" / "paper" / "dqn"
    runner = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not (checkpoints / "CartPole-v1_0" / "latest").is_file() and runner.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    runner.send_signal(signal.SIGTERM)
    out, err = runner.communicate(timeout=300)
    assert runner.returncode == 143, out[-2000:] + err[-3000:]
    assert "stopped dqn CartPole-v1 seed 0 by SIGTERM after " in out and "FAILED" not in out
    assert "Stopped by SIGTERM; the same command goes on from the runs' checkpoints" in err
    # The run's checkpoint is kept and is of the step it stopped at; it was not recorded; the second run never started
    latest = int((checkpoints / "CartPole-v1_0" / "latest").read_text())
    state = json.loads((checkpoints / "CartPole-v1_0" / str(latest) / "checkpoint.json").read_text())
    assert state["num_timesteps"] == latest >= 500
    assert not list((root / "paper").glob("dqn/CartPole-v1_*/*.json")) and not (checkpoints / "CartPole-v1_1").exists()
    dry_run = subprocess.run([*command, "--dry-run"], capture_output=True, text=True, timeout=120)
    assert f"(resumes at step {latest})" in dry_run.stdout, dry_run.stdout + dry_run.stderr
