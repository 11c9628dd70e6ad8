"""
What ``python -m sb3_offon.train`` says to a new user's first mistakes and to Ctrl-C: an unknown ``--algo``, an env
whose actions the algorithm cannot take, an env without bundled settings, a run interrupted with or without checkpoints.

The command line runs in this process (``main()``), most of it stopped before training or on a budget of a few hundred
steps; one test sends a real SIGINT to a subprocess (slow).
"""

import json
import shlex
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
from gymnasium import spaces
from helpers import hide_minatar, interrupt_after_checkpoint, run_train
from rl_zoo3.exp_manager import ExperimentManager
from stable_baselines3 import DQN, PPO

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.enjoy import main as enjoy_main
from sb3_offon.enjoy import no_model_in_one_line
from sb3_offon.resume import Checkpoint
from sb3_offon.train import INTERRUPTED, interruption_line, resume_command
from sb3_offon.zoo import ALGOS, OffOnExperimentManager
from sb3_offon.zoo_checks import (
    HYPERPARAMS_DIR,
    ZOO_HYPERPARAMS_DIR,
    UnsupportedActionSpaceError,
    check_action_space,
    default_settings_note,
)

PROG = "python -m sb3_offon.train"
# A short run: learning starts within it, a few gradient steps per 50 env steps; checkpoints at rollout starts (every 50)
SHORT = ["--eval-freq", "-1", "--seed", "0", "--hyperparams", "learning_starts:100", "train_freq:50", "gradient_steps:2"]
# What a MinAtar id says without MinAtar installed, as written out (a changed word here is a changed message)
MINATAR_MISSING = (
    "The MinAtar games need the optional 'minatar' dependencies (module 'minatar' is missing): "
    'pip install -e ".[minatar]" in a clone of the source, or pip install "sb3-offon[minatar]"'
)


def run_enjoy(monkeypatch: pytest.MonkeyPatch, *arguments: str) -> int | str | None:
    """``sb3_offon.enjoy``'s ``main()`` on ``arguments``, without rendering: the status of the ``SystemExit`` it ends with."""
    monkeypatch.setattr(sys, "argv", ["sb3_offon.enjoy", *arguments, "--no-render", "-n", "10"])
    with pytest.raises(SystemExit) as raised:
        enjoy_main()
    return raised.value.code


def no_training(monkeypatch: pytest.MonkeyPatch) -> list:
    """The command line up to the model and its warnings, without training or saving; the models it made."""
    models: list = []
    monkeypatch.setattr(OffOnExperimentManager, "learn", lambda self, model: models.append(model))
    monkeypatch.setattr(ExperimentManager, "save_trained_model", lambda self, model: None)
    return models


def error_line(capsys: pytest.CaptureFixture) -> str:
    """The one line on stderr (a traceback or a second line fails)."""
    (line,) = capsys.readouterr().err.strip().splitlines()
    return line


# --- an unknown --algo ------------------------------------------------------------------------------------------------


def test_an_unknown_algo_is_one_line_with_close_matches(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    assert run_train(monkeypatch, "--algo", "offon_qrdn", "--env", "CartPole-v1") == 2
    assert error_line(capsys) == (
        f"{PROG}: error: unknown --algo 'offon_qrdn'; close matches: offon_qrdqn, offon_dqn, offon_paper "
        "(--help lists them all)"
    )
    assert run_train(monkeypatch, "--algo=zzz") == 2
    assert error_line(capsys) == f"{PROG}: error: unknown --algo 'zzz'; no name is close to it (--help lists them all)"


@pytest.mark.parametrize("typed, name", [("OffOnDQN", "offon_dqn"), ("OffOnQRDQN", "offon_qrdqn"), ("QRDQN", "qrdqn")])
def test_a_class_name_for_algo_points_to_its_name(typed: str, name: str, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    assert run_train(monkeypatch, "--algo", typed, "--env", "CartPole-v1") == 2
    assert error_line(capsys).startswith(f"{PROG}: error: unknown --algo '{typed}'; close matches: {name}")


def test_help_still_lists_the_algorithms(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    assert run_train(monkeypatch, "--help") == 0
    out = capsys.readouterr().out
    head, _, usage = out.partition("usage: ")
    # The opening paragraph names each, the --algo choices hold each
    choices = usage[usage.index("--algo {") + len("--algo {") :].split("}")[0].replace("\n", "").replace(" ", "")
    for name in ALGOS:
        assert f"\n  {name} " in head and name in choices.split(","), name


# --- a MinAtar game without MinAtar -----------------------------------------------------------------------------------


def test_a_minatar_game_without_minatar_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    # The README's pick for MinAtar-like games, on an install with the zoo extra only: MinAtar's import fails as an
    # uninstalled package's does
    hide_minatar(monkeypatch)
    no_training(monkeypatch)
    assert run_train(monkeypatch, "--algo", "qrdqn_nstep", "--env", "MinAtar/Breakout-v0", "-f", str(tmp_path)) == 1
    assert error_line(capsys) == f"{PROG}: error: {MINATAR_MISSING}"


# --- replaying from a folder with no saved model -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "made, words",
    [
        ([], "The {folder}/offon_dqn folder was not found"),  # -f names a folder training never wrote
        (["offon_dqn"], "No model found for offon_dqn on CartPole-v1, path: {folder}/offon_dqn/CartPole-v1.zip"),
    ],
)
def test_enjoy_without_a_saved_model_is_one_line(
    made: list[str], words: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    for name in made:
        (tmp_path / name).mkdir()
    assert run_enjoy(monkeypatch, "--algo", "offon_dqn", "--env", "CartPole-v1", "-f", str(tmp_path)) == 2
    assert error_line(capsys) == (
        f"python -m sb3_offon.enjoy: error: {words.format(folder=tmp_path)}; -f takes the folder that training's -f wrote"
    )


def test_enjoy_a_minatar_game_without_minatar_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    # A model saved where MinAtar was installed, replayed where it is not: the env is made before the model is loaded
    (tmp_path / "qrdqn_nstep").mkdir()
    (tmp_path / "qrdqn_nstep" / "MinAtar-Breakout-v0.zip").write_bytes(b"")
    hide_minatar(monkeypatch)
    assert run_enjoy(monkeypatch, "--algo", "qrdqn_nstep", "--env", "MinAtar/Breakout-v0", "-f", str(tmp_path)) == 1
    assert error_line(capsys) == f"python -m sb3_offon.enjoy: error: {MINATAR_MISSING}"


def test_enjoy_keeps_other_errors() -> None:
    with pytest.raises(ValueError, match="something else"), no_model_in_one_line():
        raise ValueError("something else")
    with pytest.raises(AssertionError), no_model_in_one_line():
        raise AssertionError("an assertion of the zoo's that is not about the model's folder")


# --- an env whose actions the algorithm cannot take -------------------------------------------------------------------


@pytest.mark.parametrize("algo, algo_class", [("offon_dqn", "OffOnDQN"), ("qrdqn", "QRDQN"), ("dqn", "DQN")])
def test_continuous_actions_are_refused_in_one_line(
    algo: str, algo_class: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    no_training(monkeypatch)
    assert run_train(monkeypatch, "--algo", algo, "--env", "Pendulum-v1", "-f", str(tmp_path)) == 2
    assert error_line(capsys) == (
        f"{PROG}: error: Pendulum-v1 has the action space Box(-2.0, 2.0, (1,), float32) (continuous): --algo {algo} "
        f"({algo_class}) needs a Discrete action space (a finite set of actions); the zoo's ppo, sac and td3 take "
        "continuous ones"
    )
    assert not any((tmp_path / algo).iterdir()), "no run folder left behind"


def test_check_action_space() -> None:
    for algo_class in (OffOnDQN, OffOnQRDQN, DQN):
        check_action_space("x", algo_class, "Some-v0", spaces.Discrete(3))
        with pytest.raises(UnsupportedActionSpaceError, match=r"MultiDiscrete\(\[2 2\]\): --algo x"):
            check_action_space("x", algo_class, "Some-v0", spaces.MultiDiscrete([2, 2]))
    # The zoo's other algorithms are left to SB3's own check
    check_action_space("ppo", PPO, "Pendulum-v1", spaces.Box(-1, 1, (1,)))


@pytest.mark.parametrize(
    "algo, env",
    [("offon_dqn", "MinAtar/Breakout-v0"), ("offon_paper", "CartPoleFallPenalty-v1"), ("dqn_mc", "MountainCarGoalBonus-v0")],
)
def test_minatar_and_the_paper_tasks_pass_the_check(
    algo: str, env: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    models = no_training(monkeypatch)
    assert run_train(monkeypatch, "--algo", algo, "--env", env, "-f", str(tmp_path), *SHORT, "buffer_size:1000") == 0
    (model,) = models
    assert isinstance(model.action_space, spaces.Discrete)
    assert "error" not in capsys.readouterr().err


# --- an env without bundled settings ----------------------------------------------------------------------------------


def test_an_env_without_settings_is_warned_about_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    no_training(monkeypatch)
    assert run_train(monkeypatch, "--algo", "offon_dqn", "--env", "CartPole-v0", "-f", str(tmp_path), "--eval-freq", "-1") == 0
    assert error_line(capsys) == (
        f"{PROG}: warning: sb3_offon/hyperparams/offon_dqn.yml has no settings for CartPole-v0: training with its "
        "'default' entry (untuned) for 1,000,000 steps (closest entries: CartPole-v1). Choose the budget with -n, the "
        "settings with --hyperparams key:value or -conf FILE"
    )
    # -n is the budget it names; an env with settings is not warned about
    assert run_train(monkeypatch, "--algo", "offon_dqn", "--env", "CartPole-v0", "-n", "5000", "-f", str(tmp_path)) == 0
    assert "'default' entry (untuned) for 5,000 steps" in error_line(capsys)
    assert run_train(monkeypatch, "--algo", "offon_dqn", "--env", "CartPole-v1", "-f", str(tmp_path), "--eval-freq", "-1") == 0
    assert capsys.readouterr().err == ""


def test_default_settings_note_only_for_bundled_files(tmp_path: Path) -> None:
    bundled = str(HYPERPARAMS_DIR / "dqn.yml")
    assert default_settings_note(bundled, "CartPole-v1", False, 50_000) is None
    assert default_settings_note(bundled, "ALE/Pong-v5", True, 10_000_000) is None  # the `atari` entry
    note = default_settings_note(bundled, "Taxi-v3", False, 1_000_000)
    assert note is not None and note.startswith("sb3_offon/hyperparams/dqn.yml has no settings for Taxi-v3")
    zoo = default_settings_note(str(ZOO_HYPERPARAMS_DIR / "ppo.yml"), "NoSuchTask-v0", False, 1_000_000)
    assert zoo is not None and zoo.startswith("rl_zoo3/hyperparams/ppo.yml has no settings for NoSuchTask-v0")
    # A file of the user's own falls back to its `default` by design
    own = tmp_path / "mine.yml"
    own.write_text("default:\n  n_timesteps: 1000\n  policy: MlpPolicy\n")
    assert default_settings_note(str(own), "Taxi-v3", False, 1000) is None
    # The paper's files have no `default` (the zoo refuses an env they lack)
    assert default_settings_note(str(HYPERPARAMS_DIR / "paper" / "dqn.yml"), "Taxi-v3", False, 1000) is None


# --- Ctrl-C -----------------------------------------------------------------------------------------------------------


def test_resume_command_replaces_the_checkpoint_folder() -> None:
    argv = ["--algo", "offon_dqn", "--checkpoint-dir", "a b", "--hyperparams", "policy_kwargs:dict(net_arch=[64])"]
    assert resume_command(argv, "a b") == (
        f"{PROG} --algo offon_dqn --hyperparams 'policy_kwargs:dict(net_arch=[64])' --resume 'a b'"
    )
    # A resumed run that was interrupted again: its --resume names the folder once
    assert resume_command(["--resume=old", "-n", "10"], "new") == f"{PROG} -n 10 --resume new"


def test_ctrl_c_with_checkpoints_says_how_to_go_on(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    command = ["--algo", "offon_dqn", "--env", "CartPole-v1", "-n", "400", "-f", "logs", "--checkpoint-freq", "100"]
    command += ["--checkpoint-dir", "ckpt", *SHORT]
    with monkeypatch.context() as patch:
        interrupt_after_checkpoint(patch, 200)
        assert run_train(patch, *command) == INTERRUPTED
    checkpoint = Checkpoint.latest("ckpt")
    assert checkpoint is not None and checkpoint.num_timesteps == 200
    line = capsys.readouterr().err.strip().splitlines()[-1]
    go_on = f"{PROG} {shlex.join(command).replace('--checkpoint-dir ckpt ', '')} --resume ckpt"
    assert (
        line
        == f"{PROG}: interrupted (Ctrl-C) at step 200 of 400; newest checkpoint: step 200 in ckpt; to go on from it: {go_on}"
    )
    # The zoo saved the model trained so far, as before
    assert (tmp_path / "logs" / "offon_dqn" / "CartPole-v1_1" / "CartPole-v1.zip").is_file()
    # The command it gives goes on to the budget
    resumed = shlex.split(line.partition("to go on from it: ")[2])
    assert resumed[:3] == shlex.split(PROG)
    assert run_train(monkeypatch, *resumed[3:]) == 0
    assert OffOnDQN.load(tmp_path / "logs" / "offon_dqn" / "CartPole-v1_2" / "CartPole-v1.zip").num_timesteps == 400


def interrupt_training(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C at OffOnDQN's first training call: the first rollout end after learning_starts (step 150 here)."""

    def interrupted(self: OffOnDQN, *args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(OffOnDQN, "train", interrupted)


def test_ctrl_c_without_checkpoints_exits_130(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    interrupt_training(monkeypatch)
    assert run_train(monkeypatch, "--algo", "offon_dqn", "--env", "CartPole-v1", "-n", "400", "-f", "logs", *SHORT) == 130
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line == (
        f"{PROG}: interrupted (Ctrl-C) at step 150 of 400, without checkpoints (--checkpoint-freq STEPS writes them): "
        "no checkpoint to resume from; the model trained so far is saved in logs/offon_dqn/CartPole-v1_1"
    )
    assert (tmp_path / "logs" / "offon_dqn" / "CartPole-v1_1" / "CartPole-v1.zip").is_file()
    # With --checkpoint-freq, before the first one
    assert (
        run_train(
            monkeypatch,
            "--algo",
            "offon_dqn",
            "--env",
            "CartPole-v1",
            "-n",
            "400",
            "-f",
            "logs",
            "--checkpoint-freq",
            "300",
            *SHORT,
        )
        == 130
    )
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"{PROG}: interrupted (Ctrl-C) at step 150 of 400, before its first checkpoint (--checkpoint-freq 300): no "
        "checkpoint to resume from; the model trained so far is saved in logs/offon_dqn/CartPole-v1_2"
    )


def test_ctrl_c_before_training(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    def interrupted(self: OffOnExperimentManager) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(OffOnExperimentManager, "create_callbacks", interrupted)
    assert (
        run_train(monkeypatch, "--algo", "dqn", "--env", "CartPole-v1", "-f", str(tmp_path), "--checkpoint-freq", "100") == 130
    )
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"{PROG}: interrupted (Ctrl-C) while the run was set up, evaluated after training or saved: no checkpoint to "
        "resume from"
    )


def test_interruption_line_outside_training_finds_the_resumed_checkpoints(tmp_path: Path) -> None:
    # A --resume interrupted in its setup: the checkpoints it resumes from are still the way to go on
    folder = tmp_path / "run" / "checkpoint"
    argv = ["--algo", "dqn", "--resume", str(tmp_path / "run")]
    (folder / "300").mkdir(parents=True)
    with zipfile.ZipFile(folder / "300" / "model.zip", "w") as model:
        model.writestr("data", "{}")
    assert interruption_line(argv, KeyboardInterrupt()).endswith("no checkpoint to resume from"), "incomplete"
    size = (folder / "300" / "model.zip").stat().st_size
    (folder / "300" / "checkpoint.json").write_text(json.dumps({"file_sizes": {"model.zip": size}}))
    assert interruption_line(argv, KeyboardInterrupt()) == (
        f"{PROG}: interrupted (Ctrl-C) while the run was set up, evaluated after training or saved; newest checkpoint: "
        f"step 300 in {folder}; to go "
        f"on from it: {PROG} --algo dqn --resume {folder}"
    )


@pytest.mark.slow
def test_a_real_sigint_exits_130_with_the_line(tmp_path: Path) -> None:
    command = [sys.executable, "-m", "sb3_offon.train", "--algo", "dqn", "--env", "CartPole-v1", "-n", "1000000"]
    command += ["-f", "logs", "--checkpoint-freq", "500", "--checkpoint-dir", "ckpt", *SHORT]
    # SIGINT at its default in the child, as from a terminal: under a shell without job control (``nohup ... &``) this
    # process may have inherited it ignored, and the child would then ignore Ctrl-C
    process = subprocess.Popen(
        command,
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 300
    while not (tmp_path / "ckpt" / "latest").is_file() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130, err
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"{PROG}: interrupted (Ctrl-C) at step ") and " of 1000000; newest checkpoint: step " in line
    assert line.endswith(" --resume ckpt") and "Traceback" not in err
