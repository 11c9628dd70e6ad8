"""Checkpoints and resumed runs (sb3_offon.resume, ``--checkpoint-freq`` and ``--resume`` of ``python -m sb3_offon.train``)."""

import itertools
import json
import os
import pickle
import re
import signal
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from helpers import interrupt_after_checkpoint
from sb3_contrib import QRDQN
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.monitor import Monitor

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.callbacks import StopOnMeanTrainingReward
from sb3_offon.resume import (
    Checkpoint,
    CheckpointError,
    RunCheckpoint,
    checkpoint_problem,
    cut_running_episodes,
    joined_monitor,
    resumed_seed,
)
from sb3_offon.train import main

BUDGET, EVERY = 4000, 1000
COMMAND = [
    "--env", "CartPole-v1", "--seed", "3", "-n", str(BUDGET), "--eval-freq", str(EVERY), "--eval-episodes", "2",
    "--checkpoint-freq", str(EVERY), "--hyperparams", "learning_starts:500", "exploration_fraction:0.5",
]  # fmt: skip


def test_joined_monitor_shifts_the_later_part_to_the_earlier_start() -> None:
    earlier = '#{"t_start": 100.0, "env_id": "CartPole-v1"}\nr,l,t\n10.0,10,1.5\n20.0,20,3.0\n'
    later = '#{"t_start": 160.5, "env_id": "CartPole-v1"}\nr,l,t\n30.0,30,2.0\n'
    assert joined_monitor(earlier, later) == (
        '#{"t_start": 100.0, "env_id": "CartPole-v1"}\nr,l,t\n10.0,10,1.5\n20.0,20,3.0\n30.0,30,62.5\n'
    )
    assert joined_monitor(None, later) == later
    # A column after t (MountainCarGoalBonus-v0's goal flag) stays in place
    extra = '#{"t_start": 101.0}\nr,l,t,goal_reached\n-90.0,90,4.0,True\n'
    assert joined_monitor('#{"t_start": 100.0}\nr,l,t,goal_reached\n', extra).splitlines()[-1] == "-90.0,90,5.0,True"


def test_cut_running_episodes_marks_the_last_transitions_as_truncations() -> None:
    # 6 transitions, 3 slots per env (SB3 divides the size by the number of envs)
    buffer = ReplayBuffer(6, spaces.Box(-1, 1, (1,)), spaces.Discrete(2), n_envs=2, handle_timeout_termination=True)
    for step in range(4):  # wraps: slot 0 holds the 4th transition
        done = np.array([step == 3, False])  # env 0's episode ends (terminally) at the last step, env 1's runs on
        buffer.add(np.zeros((2, 1)), np.ones((2, 1)), np.zeros(2), np.ones(2), done, [{}, {}])
    cut_running_episodes(buffer)
    assert buffer.pos == 1 and buffer.full
    np.testing.assert_array_equal(buffer.dones[0], [1, 1])
    np.testing.assert_array_equal(buffer.timeouts[0], [0, 1])  # the terminal one stays terminal
    np.testing.assert_array_equal(buffer.dones[1:], 0)  # older transitions untouched
    empty = ReplayBuffer(3, spaces.Box(-1, 1, (1,)), spaces.Discrete(2), handle_timeout_termination=True)
    cut_running_episodes(empty)
    assert not empty.dones.any()


def test_resumed_seed_depends_on_seed_and_step() -> None:
    assert resumed_seed(3, 2000) == resumed_seed(3, 2000)
    assert len({resumed_seed(3, 2000), resumed_seed(3, 3000), resumed_seed(4, 2000)}) == 3
    assert 0 <= resumed_seed(None, 0) < 2**31


def test_run_checkpoint_rejects_a_bad_frequency(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="`every`"):
        RunCheckpoint(tmp_path, 0)


def train(monkeypatch: pytest.MonkeyPatch, folder: Path, algo: str, *extra: str, hyperparams: tuple[str, ...] = ()) -> Path:
    """Train through the command line in-process, logs in ``folder`` (``hyperparams``: more ``--hyperparams``); the run's
    log folder."""
    argv = ["sb3_offon.train", "--algo", algo, *COMMAND, *hyperparams, "-f", str(folder), *extra]
    monkeypatch.setattr(sys, "argv", argv)
    main()
    (run,) = (folder / algo).iterdir()
    return run


def interrupted(
    monkeypatch: pytest.MonkeyPatch, folder: Path, algo: str, *extra: str, after: int, hyperparams: tuple[str, ...] = ()
) -> Path:
    """:func:`train`, cut short by Ctrl-C just after its first checkpoint at or after step ``after``; the run's log folder."""
    with monkeypatch.context() as patch:
        interrupt_after_checkpoint(patch, after)
        return train(patch, folder, algo, *extra, hyperparams=hyperparams)


def monitor_rows(path: Path) -> list[list[float]]:
    return [[float(cell) for cell in line.split(",")] for line in path.read_text().splitlines()[2:]]


@pytest.mark.parametrize(
    "algo, algo_class",
    [("offon_dqn", OffOnDQN), ("dqn_nstep", DQN), ("qrdqn", QRDQN), ("offon_qrdqn", OffOnQRDQN), ("qrdqn_nstep", QRDQN)],
)
@pytest.mark.slow
def test_an_interrupted_run_resumes_as_the_uninterrupted_one_goes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, algo: str, algo_class: type[DQN]
) -> None:
    whole = train(monkeypatch, tmp_path / "whole", algo)
    cut = interrupted(monkeypatch, tmp_path / "cut", algo, after=2000)
    checkpoint = Checkpoint.latest(cut / "checkpoint")
    # CartPole's settings collect 256 steps between gradient phases: the checkpoint is at the rollout start after 2000
    assert checkpoint is not None and checkpoint.num_timesteps == 2048 and checkpoint.total_timesteps == BUDGET
    # The buffer resumes as it was: n-step DQN's keeps its n, the cut transitions are marked when it is loaded
    with open(checkpoint.folder / "replay_buffer.pkl", "rb") as file:
        buffer = pickle.load(file)
    assert buffer.pos == 2048 and getattr(buffer, "n_steps", 1) == (10 if algo in ("dqn_nstep", "qrdqn_nstep") else 1)
    cut_evaluations = np.load(cut / "evaluations.npz")
    np.testing.assert_array_equal(cut_evaluations["timesteps"], [1000, 2000])

    # The interrupted run's log folder names its checkpoint/ folder. SB3's warning that a saved n-step model's n_steps
    # is ignored on load (it is not: its saved buffer arguments hold it) is not passed on
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        resumed = train(monkeypatch, tmp_path / "resumed", algo, "--resume", str(cut))
    assert not [warning for warning in caught if "is ignored because a custom" in str(warning.message)]

    evaluations = np.load(resumed / "evaluations.npz")
    np.testing.assert_array_equal(evaluations["timesteps"], [1000, 2000, 3000, 4000])
    np.testing.assert_array_equal(evaluations["results"][:2], cut_evaluations["results"])
    final, reference = (algo_class.load(run / "CartPole-v1.zip") for run in (resumed, whole))
    # The step count, gradient steps, target-update counter and epsilon schedule went on as in the uninterrupted run
    for attribute in ("num_timesteps", "_n_updates", "_n_calls", "exploration_rate", "_total_timesteps"):
        assert getattr(final, attribute) == getattr(reference, attribute), attribute
    # The monitor file holds the episodes of both parts, in order, under the first part's header
    joined, first = resumed / "0.monitor.csv", cut / "0.monitor.csv"
    assert joined.read_text().splitlines()[0] == first.read_text().splitlines()[0]
    rows, first_rows = monitor_rows(joined), monitor_rows(first)
    assert rows[: len(first_rows)] == first_rows and len(rows) > len(first_rows)
    assert sum(row[1] for row in rows) <= BUDGET  # every step counted once (the cut episode is in neither part)
    assert all(later[2] >= earlier[2] for earlier, later in itertools.pairwise(rows))
    # A run that reaches its budget leaves no checkpoint behind
    assert not (cut / "checkpoint").exists()


def model_state(model: OffOnDQN) -> dict:
    """What a resumed run must start from: networks, optimizer, counters and replay buffer, copied."""
    buffer = model.replay_buffer
    arrays = ("observations", "next_observations", "actions", "rewards", "timeouts", "mc_returns", "next_actions")
    return {
        "policy": {key: value.clone() for key, value in model.policy.state_dict().items()},
        "optimizer": pickle.loads(pickle.dumps(model.policy.optimizer.state_dict())),
        "counters": [getattr(model, name) for name in ("num_timesteps", "_n_calls", "_n_updates", "_episode_num")],
        "buffer": {name: getattr(buffer, name).copy() for name in arrays},
        "dones": buffer.dones.copy(),
        "bookkeeping": (buffer.pos, buffer.full, buffer._n_adds),
    }


def test_the_resumed_model_is_the_checkpointed_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    states = {}
    save, prepare = RunCheckpoint.save, Checkpoint.prepare

    def save_and_keep(self: RunCheckpoint) -> Checkpoint:
        states["live"] = model_state(self.model)
        return save(self)

    def prepare_and_keep(self: Checkpoint, model: OffOnDQN, *args: object) -> None:
        prepare(self, model, *args)
        states["loaded"] = model_state(model)

    with monkeypatch.context() as patch:
        patch.setattr(RunCheckpoint, "save", save_and_keep)
        interrupt_after_checkpoint(patch, 2000)
        cut = train(patch, tmp_path / "cut", "offon_dqn")
    monkeypatch.setattr(Checkpoint, "prepare", prepare_and_keep)
    train(monkeypatch, tmp_path / "resumed", "offon_dqn", "--resume", str(cut))
    live, loaded = states["live"], states["loaded"]
    assert live["counters"] == loaded["counters"] and live["bookkeeping"] == loaded["bookkeeping"]
    for key, value in live["policy"].items():
        assert th.equal(value, loaded["policy"][key]), key
    for group, values in live["optimizer"]["state"].items():
        for key, value in values.items():
            assert th.equal(value, loaded["optimizer"]["state"][group][key]), (group, key)
    # The buffer is the checkpoint's, but for the episode cut at the checkpoint: its last transition is now a
    # truncation (done and timed out) and its returns, unknown while it ran, are closed (bootstrapped)
    last = live["bookkeeping"][0] - 1
    live_returns, loaded_returns = live["buffer"].pop("mc_returns"), loaded["buffer"]["mc_returns"]
    for name, value in live["buffer"].items():
        np.testing.assert_array_equal(np.delete(value, last, axis=0), np.delete(loaded["buffer"][name], last, axis=0), name)
    assert loaded["dones"][last, 0] and loaded["buffer"]["timeouts"][last, 0]
    running = np.isnan(live_returns[: last + 1, 0])
    assert running[last] and not np.isnan(loaded_returns[: last + 1, 0]).any()
    np.testing.assert_array_equal(live_returns[: last + 1][~running], loaded_returns[: last + 1][~running])


@pytest.mark.slow
def test_two_envs_resume_with_both_monitor_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    two = ("n_envs:2",)
    whole = train(monkeypatch, tmp_path / "whole", "offon_dqn", hyperparams=two)
    cut = interrupted(monkeypatch, tmp_path / "cut", "offon_dqn", hyperparams=two, after=2000)
    # Two envs collect 2 x 256 steps between gradient phases
    checkpoint = Checkpoint.latest(cut / "checkpoint")
    assert checkpoint is not None and checkpoint.num_timesteps == 2048
    with open(checkpoint.folder / "replay_buffer.pkl", "rb") as file:
        buffer = pickle.load(file)
    # Each env's episodes run apart (CartPole's lengths differ): the buffer's episode bookkeeping is per env
    assert buffer.n_envs == 2 and buffer.pos == 1024
    resumed = train(monkeypatch, tmp_path / "resumed", "offon_dqn", "--resume", str(cut), hyperparams=two)
    np.testing.assert_array_equal(np.load(resumed / "evaluations.npz")["timesteps"], [1000, 2000, 3000, 4000])
    final, reference = (OffOnDQN.load(run / "CartPole-v1.zip") for run in (resumed, whole))
    for attribute in ("num_timesteps", "_n_updates", "_n_calls", "exploration_rate", "mc_prob"):
        assert getattr(final, attribute) == getattr(reference, attribute), attribute
    for name in ("0.monitor.csv", "1.monitor.csv"):
        first_rows = monitor_rows(cut / name)
        rows = monitor_rows(resumed / name)
        assert rows[: len(first_rows)] == first_rows and len(rows) > len(first_rows), name
    assert sum(row[1] for name in ("0.monitor.csv", "1.monitor.csv") for row in monitor_rows(resumed / name)) <= 4096


def test_a_normalised_env_resumes_with_its_statistics(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    normalised = ("normalize:True",)
    cut = interrupted(monkeypatch, tmp_path / "cut", "dqn", hyperparams=normalised, after=2000)
    resumed = train(monkeypatch, tmp_path / "resumed", "dqn", "--resume", str(cut), hyperparams=normalised)
    with open(resumed / "CartPole-v1" / "vecnormalize.pkl", "rb") as file:
        statistics = pickle.load(file)
    # The observation statistics went on from the checkpoint's 2,048 steps (restarted, they would count about 2,048)
    assert statistics.obs_rms.count > 4000


def refused(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, folder: Path, algo: str, *extra: str) -> str:
    """The one line on stderr with which the command line refuses to run (exit status 2); no run folder is left."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        train(monkeypatch, folder, algo, *extra)
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("python -m sb3_offon.train: error: ")
    assert not (folder / algo).exists() or not any((folder / algo).iterdir()), "a refused run leaves no run folder"
    return lines[0]


@pytest.mark.slow
def test_resume_refuses_another_budget_algorithm_or_hyperparameters(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    cut = interrupted(monkeypatch, tmp_path / "cut", "dqn", after=1000)
    state = json.loads((cut / "checkpoint" / "1024" / "checkpoint.json").read_text())
    assert state["num_timesteps"] == 1024 and state["resumed_at"] == []
    assert state["algorithm"] == "DQN" and state["run_config"]["algo"] == "dqn"
    assert state["run_config"]["hyperparams"]["learning_starts"] == 500
    checkpoint = str(cut / "checkpoint")
    line = refused(monkeypatch, capsys, tmp_path / "longer", "dqn", "--resume", checkpoint, "-n", "5000")
    assert "budget of 4000 steps, this command trains 5000" in line
    line = refused(monkeypatch, capsys, tmp_path / "other", "offon_dqn", "--resume", checkpoint)
    assert "the run was made with --algo dqn, this command has --algo offon_dqn" in line
    changed = ("--hyperparams", "learning_starts:600", "exploration_fraction:0.5")
    line = refused(monkeypatch, capsys, tmp_path / "changed", "dqn", "--resume", checkpoint, *changed)
    assert line.endswith("other hyperparameters than this command gives: learning_starts 500 there, 600 here")
    line = refused(monkeypatch, capsys, tmp_path / "none", "dqn", "--resume", str(tmp_path / "nowhere"))
    assert "no checkpoint there" in line
    with pytest.raises(ValueError, match="holds a DQN model, not a OffOnDQN"):
        Checkpoint.latest(checkpoint).load_model(OffOnDQN, None)


@pytest.mark.slow
def test_resume_refuses_an_offon_dqn_checkpoint_with_algo_dqn(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    # Before, `--algo dqn` loaded dqn.yml and went on as SB3's DQN from OffOnDQN's checkpoint, the budget alone checked
    cut = interrupted(monkeypatch, tmp_path / "cut", "offon_dqn", after=1000)
    line = refused(monkeypatch, capsys, tmp_path / "other", "dqn", "--resume", str(cut))
    assert "the run was made with --algo offon_dqn, this command has --algo dqn" in line


@pytest.mark.slow
def test_a_damaged_checkpoint_falls_back_to_the_one_before(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    cut = interrupted(monkeypatch, tmp_path / "cut", "dqn", after=2000)
    folder = cut / "checkpoint"
    assert sorted(path.name for path in folder.iterdir()) == ["1024", "2048", "latest"], "the two newest kept"
    newest, before = folder / "2048", folder / "1024"
    model = (newest / "model.zip").read_bytes()
    (newest / "model.zip").write_bytes(model[: len(model) // 2])
    truncated = rf"2048: model.zip truncated \({len(model) // 2} of {len(model)} bytes\): resuming from the one of step 1024"
    with pytest.warns(UserWarning, match=truncated):
        assert Checkpoint.latest(folder).num_timesteps == 1024
    (newest / "model.zip").write_bytes(model)
    (newest / "checkpoint.json").unlink()
    with pytest.warns(UserWarning, match=r"step 2048: no checkpoint.json \(its writing was cut off\)"):
        assert Checkpoint.latest(folder).num_timesteps == 1024
    (before / "replay_buffer.pkl").unlink()
    expected = r"No complete checkpoint in .*: step 2048: no checkpoint.json .*; step 1024: replay_buffer.pkl missing$"
    with pytest.raises(CheckpointError, match=expected):
        Checkpoint.latest(folder)
    assert re.search(expected, refused(monkeypatch, capsys, tmp_path / "both", "dqn", "--resume", str(cut)))


@pytest.mark.slow
def test_a_run_resumes_from_the_checkpoint_before_a_damaged_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cut = interrupted(monkeypatch, tmp_path / "cut", "dqn", after=2000)
    with open(cut / "checkpoint" / "2048" / "replay_buffer.pkl", "r+b") as file:
        file.truncate(100)
    fallback_monitor = (cut / "checkpoint" / "1024" / "0.monitor.csv").read_text()
    with pytest.warns(UserWarning, match="step 2048: replay_buffer.pkl truncated"):
        resumed = train(monkeypatch, tmp_path / "resumed", "dqn", "--resume", str(cut))
    evaluations = np.load(resumed / "evaluations.npz")
    np.testing.assert_array_equal(evaluations["timesteps"], [1000, 2000, 3000, 4000])
    # Resumed at step 1024: its training episodes go on from the ones that checkpoint holds
    assert (resumed / "0.monitor.csv").read_text().startswith(fallback_monitor)
    assert len(monitor_rows(resumed / "0.monitor.csv")) > len(fallback_monitor.splitlines()) - 2


def test_a_run_resumed_after_its_last_evaluation_keeps_them(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # A budget of 3,500 steps evaluated every 1,000: cut after the checkpoint at 3,072, the resumed part evaluates no
    # more, and its file must still hold the three evaluations made before the cut
    budget = ("-n", "3500")
    cut = interrupted(monkeypatch, tmp_path / "cut", "dqn", *budget, after=3000)
    assert Checkpoint.latest(cut / "checkpoint").num_timesteps == 3072
    before = np.load(cut / "evaluations.npz")
    resumed = train(monkeypatch, tmp_path / "resumed", "dqn", "--resume", str(cut), *budget)
    after = np.load(resumed / "evaluations.npz")
    np.testing.assert_array_equal(after["timesteps"], [1000, 2000, 3000])
    np.testing.assert_array_equal(after["results"], before["results"])
    assert not (cut / "checkpoint").exists(), "the run reached its budget"


def stop_rule(threshold: float, window: int) -> str:
    """The ``--hyperparams`` entry of a stop rule on the mean training episode length (the paper's CartPole rule)."""
    settings = f"{{'threshold':{threshold},'window':{window},'episode_key':'l'}}"
    return f"callback:[{{'sb3_offon.callbacks.StopOnMeanTrainingReward':{settings}}}]"


def test_a_run_its_stop_rule_ends_is_finished(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # A mean length of 5 over 100 episodes: reached once the window is full, after the checkpoint at 1,024 steps
    run = train(monkeypatch, tmp_path / "stopped", "dqn", hyperparams=(stop_rule(5, 100),))
    record = json.loads((run / "stopped.json").read_text())
    assert record["callback"] == "StopOnMeanTrainingReward" and 1024 < record["num_timesteps"] < BUDGET
    assert np.load(run / "evaluations.npz")["timesteps"][-1] < BUDGET
    assert not (run / "checkpoint").exists(), "a finished run leaves no checkpoint"


def test_a_resumed_run_keeps_its_stop_rule_window(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    never = (stop_rule(10**9, 100),)
    cut = interrupted(monkeypatch, tmp_path / "cut", "dqn", hyperparams=never, after=2000)
    assert not (cut / "stopped.json").exists(), "cut short by Ctrl-C, not ended by its rule"
    checkpoint = Checkpoint.latest(cut / "checkpoint")
    ((name, state),) = checkpoint.callback_states
    episodes = monitor_rows(cut / "0.monitor.csv")
    assert name == "StopOnMeanTrainingReward" and state["n_episodes"] == len(episodes)
    assert state["recent"] == [row[1] for row in episodes[-100:]], "the window holds the last 100 episode lengths"
    restored = []
    original = StopOnMeanTrainingReward.set_state
    monkeypatch.setattr(StopOnMeanTrainingReward, "set_state", lambda self, s: (restored.append(s), original(self, s)))
    train(monkeypatch, tmp_path / "resumed", "dqn", "--resume", str(cut), hyperparams=never)
    assert restored == [state]
    with pytest.raises(ValueError, match="resume a run with the callbacks it was started with"):
        checkpoint.restore_callbacks([])


def evaluation_callback(log_path: Path) -> EvalCallback:
    # SB3's EvalCallback keeps its evaluations (which a checkpoint saves) only when it has a log_path
    return EvalCallback(Monitor(gym.make("CartPole-v1")), eval_freq=500, n_eval_episodes=2, log_path=str(log_path), verbose=0)


def python_run(folder: Path, callbacks: list) -> tuple[OffOnDQN, EvalCallback, list]:
    """A small OffOnDQN run on CartPole-v1 with evaluations and checkpoints every 500 steps, from Python."""
    model = OffOnDQN("MlpPolicy", "CartPole-v1", learning_starts=200, train_freq=4, buffer_size=5000, seed=5)
    evaluations = evaluation_callback(folder)
    checkpoints = RunCheckpoint(folder, 500, evaluations)
    return model, evaluations, [evaluations, checkpoints, *callbacks]


def test_the_python_way_resumes_as_the_command_line_does(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    whole, whole_evaluations, callbacks = python_run(tmp_path / "whole", [])
    whole.learn(2000, callback=callbacks)
    cut, _, callbacks = python_run(tmp_path / "cut", [])
    with monkeypatch.context() as patch, pytest.raises(KeyboardInterrupt):
        interrupt_after_checkpoint(patch, 1000)
        cut.learn(2000, callback=callbacks)
    checkpoint = Checkpoint.latest(tmp_path / "cut")
    assert checkpoint is not None and checkpoint.num_timesteps == 1000
    evaluations = evaluation_callback(tmp_path / "resumed")
    resumed = checkpoint.load_model(OffOnDQN, gym.make("CartPole-v1"), evaluations)
    assert resumed.replay_buffer.size() == 1000 and evaluations.evaluations_timesteps == [500, 1000]
    resumed.learn(
        checkpoint.total_timesteps - resumed.num_timesteps,
        reset_num_timesteps=False,
        callback=[evaluations, RunCheckpoint(tmp_path / "cut", 500, evaluations, resumed_from=checkpoint)],
    )
    assert evaluations.evaluations_timesteps == whole_evaluations.evaluations_timesteps == [500, 1000, 1500, 2000]
    for attribute in ("num_timesteps", "_n_updates", "_n_calls", "exploration_rate", "mc_prob"):
        assert getattr(resumed, attribute) == getattr(whole, attribute), attribute


@pytest.fixture
def python_sigint_handler() -> Iterator[None]:
    """
    Python's own SIGINT handler for the test, as in a terminal: a process started in the background by a shell without
    job control (``nohup ... &``) inherits SIGINT ignored, and an ignored SIGINT rightly interrupts nothing.
    """
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.usefixtures("python_sigint_handler")
def test_a_ctrl_c_while_a_checkpoint_is_written_takes_effect_once_it_is_written(tmp_path: Path, monkeypatch) -> None:
    """A SIGINT raised inside torch's zip writer would end the run in a RuntimeError from the writer's cleanup; held
    until the checkpoint is written, it ends the run as a KeyboardInterrupt with a complete checkpoint behind it."""
    handler = signal.getsignal(signal.SIGINT)
    model, _, callbacks = python_run(tmp_path, [])
    original_save = type(model).save
    interrupted_at: list[int] = []

    def save_with_a_ctrl_c(self, path, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        if self.num_timesteps == 1000:
            interrupted_at.append(self.num_timesteps)
            os.kill(os.getpid(), signal.SIGINT)  # delivered now, in the middle of the checkpoint
        original_save(self, path, *args, **kwargs)

    monkeypatch.setattr(type(model), "save", save_with_a_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        model.learn(2000, callback=callbacks)
    assert interrupted_at == [1000] and model.num_timesteps == 1000
    checkpoint = Checkpoint.latest(tmp_path)
    assert checkpoint is not None and checkpoint.num_timesteps == 1000 and checkpoint_problem(checkpoint.folder) is None
    assert signal.getsignal(signal.SIGINT) is handler  # Python's own handler back in place
