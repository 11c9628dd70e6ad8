"""``python -m sb3_offon.train --help`` names the algorithms this package adds; a bad OffOnDQN argument is one line."""

import subprocess
import sys
from pathlib import Path

import pytest
from stable_baselines3 import DQN

from sb3_offon import OffOnDQN
from sb3_offon.train import argument_errors_in_one_line, help_description, one_thread_by_default
from sb3_offon.zoo import ALGO_SUMMARIES, ALGOS

TIMEOUT = 300


def test_help_description_lists_every_registered_name() -> None:
    # Built from the dict at run time: a name added to ALGOS appears without touching the text
    text = help_description({**ALGOS, "offon_new": OffOnDQN}, ALGO_SUMMARIES)
    lines = text.splitlines()
    # A name and its class on one line (two indents), what it trains on the next (deeper) where a summary exists
    rows = {line.split()[0]: line.split()[1] for line in lines if line.startswith("  ") and not line.startswith("   ")}
    assert list(rows) == [*ALGOS, "offon_new"]
    for name, summary in ALGO_SUMMARIES.items():
        row = next(index for index, line in enumerate(lines) if line.split()[:1] == [name])
        assert lines[row + 1].strip() == summary
    assert set(ALGO_SUMMARIES) == set(ALGOS), "every name says what it trains"
    assert "OffOnDQN's defaults" in ALGO_SUMMARIES["offon_dqn"] and "PAPER_TARGETS" in ALGO_SUMMARIES["offon_paper"]
    assert ALGO_SUMMARIES["offon_lambda_choice"] == "former name of offon_dqn"
    assert rows["offon_dqn"] == "sb3_offon.OffOnDQN" and rows["dqn_nstep"] == "stable_baselines3.DQN"
    assert "docs/offon_dqn.md" in text and "hyperparams" in text
    assert max(len(line) for line in text.splitlines()) <= 100


def test_other_value_errors_keep_their_traceback() -> None:
    # Raised outside the package (the zoo's, SB3's): not ours to reword
    with pytest.raises(ValueError, match="must be one of"), argument_errors_in_one_line():
        raise ValueError("`mc_mixing` must be one of ('a',), got 'b'")


def test_argument_error_in_the_package_is_one_line(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as raised, argument_errors_in_one_line():
        OffOnDQN("MlpPolicy", "CartPole-v1", sarsa_target="nope")
    assert raised.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "`sarsa_target` must be one of" in err and "'nope'" in err


@pytest.mark.slow
def test_help_and_bad_hyperparameter_on_the_command_line(tmp_path: Path) -> None:
    commands = {
        "help": ["--help"],
        "bad": ["--algo", "offon_dqn", "--env", "CartPole-v1", "-n", "100", "-f", "logs", "--hyperparams", "mc_mixing:foo"],
    }
    processes = {
        name: subprocess.Popen(
            [sys.executable, "-m", "sb3_offon.train", *arguments],
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name, arguments in commands.items()
    }
    results = {name: (*process.communicate(timeout=TIMEOUT), process.returncode) for name, process in processes.items()}

    out, err, returncode = results["help"]
    assert returncode == 0, err
    # The opening paragraph, before argparse's usage, names every added algorithm; the zoo's options follow
    head, _, rest = out.partition("usage: ")
    for name in ALGOS:
        assert f"\n  {name} " in head, name
    assert "--hyperparams" in rest and "--algo" in rest and "offon_dqn" in rest
    assert DQN.__name__ in head
    # The options this package adds to the zoo's: checkpoints to resume from
    assert all(f"{option} " in rest for option in ("--checkpoint-freq", "--checkpoint-dir", "--resume"))

    out, err, returncode = results["bad"]
    assert returncode == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "`mc_mixing` must be one of ('sample', 'convex'" in lines[0] and "got 'foo'" in lines[0]
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["--algo", "dqn"], ["--algo", "dqn", "--num-threads", "1"]),
        (["--algo", "dqn", "--num-threads", "4"], ["--algo", "dqn", "--num-threads", "4"]),
        (["--num-threads=-1", "--algo", "dqn"], ["--num-threads=-1", "--algo", "dqn"]),
    ],
)
def test_one_thread_unless_the_command_line_says(argv: list[str], expected: list[str]) -> None:
    assert one_thread_by_default(argv) == expected
    assert "--num-threads" in help_description(ALGOS)


def test_an_unknown_env_is_one_line_with_close_matches() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "sb3_offon.train", "--algo", "dqn", "--env", "CartPol-v1", "-n", "10"],
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )
    assert result.returncode == 2
    # One line, no traceback; the closest registered ids first (Gymnasium's CartPole-v1 the closest of all)
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("python -m sb3_offon.train: error: unknown environment 'CartPol-v1'; close matches: CartPole-v1")


@pytest.mark.parametrize(
    "algo, hyperparams, expected",
    [
        ("offon_dqn", ["lerning_rate:0.001"], "unknown hyperparameter 'lerning_rate' for --algo offon_dqn (OffOnDQN); "
         "close matches: learning_rate"),
        ("dqn", ["lerning_rate:0.001"], "unknown hyperparameter 'lerning_rate' for --algo dqn (DQN); "
         "close matches: learning_rate"),
        ("qrdqn", ["policy_kwargs:dict(n_quantiles=0)"], "`n_quantiles` must be a positive integer, got 0"),
        ("offon_qrdqn", ["buffer_size:0"], "`buffer_size` must be a positive integer, got 0"),
        # SB3's own check, in its constructor
        ("dqn", ["optimize_memory_usage:True"], "invalid hyperparameter (--hyperparams or the YAML file): ReplayBuffer "
         "does not support optimize_memory_usage = True and handle_timeout_termination = True simultaneously"),
    ],
)  # fmt: skip
def test_a_bad_hyperparameter_is_one_line_and_leaves_no_run_folder(
    algo: str, hyperparams: list[str], expected: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    from sb3_offon.train import main

    argv = ["sb3_offon.train", "--algo", algo, "--env", "CartPole-v1", "-n", "100", "-f", str(tmp_path), "--hyperparams"]
    monkeypatch.setattr(sys, "argv", [*argv, *hyperparams])
    with pytest.raises(SystemExit) as raised:
        main()
    assert raised.value.code == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("python -m sb3_offon.train: error: ") and expected in line, line
    assert not (tmp_path / algo).exists() or not any((tmp_path / algo).iterdir()), "no run folder left behind"
