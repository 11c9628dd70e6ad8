"""
``python -m sb3_offon.train`` / ``python -m sb3_offon.enjoy`` end to end, in a temporary folder.

The commands are launched in parallel subprocesses (one torch thread each) and shared by the tests of this module:
most of their time is the interpreter's start, which parallelises well.
"""

import csv
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import optuna
import pytest
import torch as th
import yaml
from rl_zoo3.utils import ALGOS

from sb3_offon import MinAtarCNN, OffOnDQN
from sb3_offon.enjoy import ReplayLoader
from sb3_offon.enjoy import main as enjoy_main
from sb3_offon.offon_dqn.policies import DuelingHead
from sb3_offon.zoo import HYPERPARAMS_DIR, register

# Ours and SB3's DQN, all from the zoo's table
register()
# Every test here reads the module's trainings (two minutes on a busy 2-core machine): all in the slow set
pytestmark = pytest.mark.slow
ALGORITHMS = ["offon_dqn", "dqn_mc", "dqn_sarsa", "dqn"]
N_STEPS = 300
TIMEOUT = 600
# Learning starts within the run so that the training code runs too; a few gradient steps per 64 env steps
SHORT = ["learning_starts:100", "train_freq:64", "gradient_steps:4"]
COMMON = ["--num-threads", "1", "--seed", "0", "-f", "logs"]


def journal(folder: Path) -> optuna.storages.JournalStorage:
    return optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(folder / "study.log")))


def run_all(commands: dict[str, list[str]], cwd: Path) -> dict[str, subprocess.CompletedProcess]:
    """Run ``python -m ...`` commands in parallel; their completed processes, output and errors merged."""
    processes = {
        name: subprocess.Popen(
            [sys.executable, "-m", *command], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        for name, command in commands.items()
    }
    results = {}
    for name, process in processes.items():
        output, _ = process.communicate(timeout=TIMEOUT)
        results[name] = subprocess.CompletedProcess(process.args, process.returncode, output)
    return results


def check(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 0, result.stdout[-5000:]
    return result.stdout


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, subprocess.CompletedProcess]]:
    """Short trainings of every algorithm, the two paper tasks, and two tuners sharing one Optuna study."""
    folder = tmp_path_factory.mktemp("cli")
    train = ["sb3_offon.train", "--env", "CartPole-v1", "-n", str(N_STEPS), *COMMON]
    commands = {
        algo: [
            *train,
            "--algo",
            algo,
            "--eval-freq",
            "150",
            "--eval-episodes",
            "2",
            "--save-freq",
            "150",
            "--tensorboard-log",
            "tb",
            "--progress",
            "--hyperparams",
            *SHORT,
        ]
        for algo in ALGORITHMS
    }
    # Environments rebuilt by name in SubprocVecEnv workers: only the registration in sb3_offon.envs makes that work
    commands["fall_penalty"] = [
        *["sb3_offon.train", "--algo", "offon_dqn", "--env", "CartPoleFallPenalty-v1", "-n", str(N_STEPS), *COMMON],
        *["--eval-freq", "-1", "--vec-env", "subproc", "--hyperparams", *SHORT, "n_envs:2"],
    ]
    commands["goal_bonus"] = [
        *["sb3_offon.train", "--algo", "dqn_mc", "--env", "MountainCarGoalBonus-v0", "-n", "450", *COMMON],
        *["--eval-freq", "-1", "--log-interval", "1", "--hyperparams", *SHORT],
    ]
    # OffOnDQN's two DQN extensions through --hyperparams: double Q-learning and a dueling network
    commands["double_dueling"] = [
        *["sb3_offon.train", "--algo", "offon_lambda_choice", "--env", "CartPole-v1", "-n", str(N_STEPS), *COMMON],
        *["--eval-freq", "-1", "--hyperparams", *SHORT, "double_q:True"],
        "policy_kwargs:dict(dueling=True, net_arch=[32, 32])",
    ]
    # No --num-threads: one torch thread all the same
    commands["default_threads"] = [
        *["sb3_offon.train", "--algo", "dqn", "--env", "CartPole-v1", "-n", "200", "--seed", "0", "-f", "logs_threads"],
        # --verbose 2: the zoo then says the number of threads it sets
        *["--eval-freq", "-1", "--verbose", "2", "--hyperparams", *SHORT],
    ]
    # A MinAtar game with its bundled settings (the MinAtar network through the YAML's policy_kwargs string)
    commands["minatar"] = [
        *["sb3_offon.train", "--algo", "offon_lambda_choice", "--env", "MinAtar/Breakout-v0", "-n", str(N_STEPS), *COMMON],
        *["--eval-freq", "-1", "--hyperparams", "learning_starts:100"],
    ]
    # Tuning into a shared Optuna storage (a journal file here; any machine that sees the file, or an RDB URL, can
    # join), into a study another worker already added a trial to: the distributed tuning path
    study = optuna.create_study(storage=journal(folder), study_name="cli", direction="maximize")
    study.add_trial(optuna.trial.create_trial(value=0.0))
    commands["optimize"] = [
        *["sb3_offon.train", "--algo", "offon_dqn", "--env", "CartPole-v1", "-n", str(N_STEPS), "-f", "tune"],
        *["--num-threads", "1", "--seed", "0", "-optimize", "--n-trials", "2", "--no-optim-plots"],
        *["--storage", "study.log", "--study-name", "cli", "--eval-episodes", "2"],
        # No pruning before 3 trials are done: every trial reports a value
        *["--n-startup-trials", "3", "--hyperparams", "learning_starts:100"],
    ]
    return folder, run_all(commands, folder)


ENJOY = ["--env", "CartPole-v1", "-f", "logs", "--no-render", "-n", "600", "--num-threads", "1"]


@pytest.fixture(scope="module")
def enjoy_cli(runs: tuple[Path, dict]) -> subprocess.CompletedProcess:
    folder, _ = runs
    # 600 steps: more than one CartPole episode (500 steps at most), so at least one ends
    return run_all({"enjoy": ["sb3_offon.enjoy", *ENJOY, "--algo", "offon_dqn"]}, folder)["enjoy"]


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_train_writes_the_zoo_layout(runs: tuple[Path, dict], algo: str) -> None:
    folder, results = runs
    check(results[algo])
    run = folder / "logs" / algo / "CartPole-v1_1"
    for name in ("CartPole-v1.zip", "best_model.zip", "rl_model_150_steps.zip", "rl_model_300_steps.zip", "0.monitor.csv"):
        assert (run / name).is_file(), name
    evaluations = np.load(run / "evaluations.npz")
    assert evaluations["timesteps"].tolist() == [150, 300]
    assert evaluations["results"].shape == (2, 2)
    assert any((folder / "tb" / "CartPole-v1").rglob("events.out.tfevents.*"))

    config = dict(yaml.load((run / "CartPole-v1" / "config.yml").read_text(), Loader=yaml.UnsafeLoader))
    args = dict(yaml.load((run / "CartPole-v1" / "args.yml").read_text(), Loader=yaml.UnsafeLoader))
    # No -conf: the bundled file (for SB3's dqn too), with the command line's overrides on top
    assert args["conf_file"] == str(HYPERPARAMS_DIR / f"{algo}.yml")
    expected = dict(yaml.safe_load((HYPERPARAMS_DIR / f"{algo}.yml").read_text())["CartPole-v1"])
    expected.update(learning_starts=100, train_freq=64, gradient_steps=4)
    assert config == expected


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_saved_model_keeps_its_class_and_targets(runs: tuple[Path, dict], algo: str) -> None:
    folder, results = runs
    check(results[algo])
    path = folder / "logs" / algo / "CartPole-v1_1" / "CartPole-v1.zip"
    model = ALGOS[algo].load(path, device="cpu")
    assert type(model) is ALGOS[algo]
    assert model.learning_starts == 100
    if algo != "dqn":
        # The variants' defaults do not override what was saved
        # offon_dqn: OffOnDQN's defaults (lambda 0.9, Peng's); the paper's variants: their coin-flip schedules
        expected = {"offon_dqn": (0.9, 0.0), "dqn_mc": (0.99, 1.0), "dqn_sarsa": (0.0, 0.99)}[algo]
        assert (model.mc_initial_prob, model.qlearning_initial_prob) == expected
        assert model._n_updates > 0


def test_enjoy_cli(enjoy_cli: subprocess.CompletedProcess) -> None:
    output = check(enjoy_cli)
    assert "Loading logs/offon_dqn/CartPole-v1_1/CartPole-v1.zip" in output
    assert "Episode Reward" in output


@pytest.mark.parametrize("algo", ["dqn_mc", "dqn_sarsa", "dqn"])
def test_enjoy(runs: tuple[Path, dict], algo: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    """The same entry point as ``python -m sb3_offon.enjoy``, in this process: it saves the interpreter's start."""
    folder, results = runs
    check(results[algo])
    monkeypatch.chdir(folder)
    monkeypatch.setattr(sys, "argv", ["enjoy", *ENJOY, "--algo", algo])
    enjoy_main()
    output = capsys.readouterr().out
    assert f"Loading logs/{algo}/CartPole-v1_1/CartPole-v1.zip" in output
    assert "Episode Reward" in output


def test_replay_loader_shrinks_the_buffer(runs: tuple[Path, dict]) -> None:
    folder, results = runs
    check(results["offon_dqn"])
    model = ReplayLoader(OffOnDQN).load(folder / "logs" / "offon_dqn" / "CartPole-v1_1" / "CartPole-v1.zip", device="cpu")
    assert model.replay_buffer.buffer_size == 1


def test_fall_penalty_task_with_subprocess_envs(runs: tuple[Path, dict]) -> None:
    folder, results = runs
    check(results["fall_penalty"])
    run = folder / "logs" / "offon_dqn" / "CartPoleFallPenalty-v1_1"
    assert (run / "CartPoleFallPenalty-v1.zip").is_file()
    n_episodes = 0
    for env_index in range(2):
        with open(run / f"{env_index}.monitor.csv") as file:
            next(file)  # the Monitor's JSON header
            for row in csv.DictReader(file):
                # Every early episode falls: +1 per step, and -100 instead of the last +1
                length = int(row["l"])
                assert length < 500
                assert float(row["r"]) == pytest.approx(length - 1 - 100)
                n_episodes += 1
    assert n_episodes > 0


def test_goal_bonus_task_logs_goal_count(runs: tuple[Path, dict]) -> None:
    folder, results = runs
    output = check(results["goal_bonus"])
    # One log dump per episode (--log-interval 1): two episodes of 200 steps within 450 steps. An untrained agent
    # does not reach the goal in 200 steps: the count stays at 0
    assert len(re.findall(r"\|\s+goal_reached\s+\|\s+0\s+\|", output)) == 2
    with open(folder / "logs" / "dqn_mc" / "MountainCarGoalBonus-v0_1" / "0.monitor.csv") as file:
        next(file)
        rows = list(csv.DictReader(file))
    # -1 each step, and the goal flag in the monitor CSV
    assert [(float(row["r"]), int(row["l"]), row["goal_reached"]) for row in rows] == [(-200.0, 200, "False")] * 2


def test_double_q_and_dueling_from_the_command_line(runs: tuple[Path, dict]) -> None:
    folder, results = runs
    check(results["double_dueling"])
    model = OffOnDQN.load(folder / "logs" / "offon_lambda_choice" / "CartPole-v1_1" / "CartPole-v1.zip", device="cpu")
    assert model.double_q is True and model._n_updates > 0
    assert model.policy.dueling is True and model.policy.net_arch == [32, 32]
    assert isinstance(model.q_net.q_net, DuelingHead) and isinstance(model.q_net_target.q_net, DuelingHead)


def test_one_torch_thread_without_num_threads(runs: tuple[Path, dict]) -> None:
    _, results = runs
    assert "Setting torch.num_threads to 1" in check(results["default_threads"])


def test_minatar_game_trains_with_its_bundled_settings(runs: tuple[Path, dict]) -> None:
    folder, results = runs
    check(results["minatar"])
    run = folder / "logs" / "offon_lambda_choice" / "MinAtar-Breakout-v0_1"
    model = OffOnDQN.load(run / "MinAtar-Breakout-v0.zip", device="cpu")
    assert isinstance(model.q_net.features_extractor, MinAtarCNN) and model._n_updates > 0
    assert isinstance(model.policy.optimizer, th.optim.RMSprop) and model.exploration_final_eps == 0.1


def test_optimize_shares_one_study(runs: tuple[Path, dict]) -> None:
    folder, results = runs
    check(results["optimize"])
    study = optuna.load_study(study_name="cli", storage=journal(folder))
    assert len(study.trials) == 3
    assert all(trial.state == optuna.trial.TrialState.COMPLETE for trial in study.trials)
    for trial in study.trials[1:]:
        # offon_dqn's sampler: the lambda and trace-cut schedules; mc_mixing stays "lambda", no Sarsa target to choose
        assert {"learning_rate", "mc_initial_prob", "qlearning_initial_prob", "loss"} <= set(trial.params)
        assert not {"mc_mixing", "sarsa_target"} & set(trial.params)
    assert list((folder / "tune" / "offon_dqn").glob("report_CartPole-v1_2-trials-300-tpe-median_*.csv"))
