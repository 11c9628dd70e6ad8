"""scripts/run_times.py: run times read from done.json records, whole runs apart from resumed ones."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import SCRIPTS, load_script

run_times = load_script("run_times")


def write_record(grid: Path, algo: str, env: str, seed: int, wall_time_s: float, resumed_at=None, returncode=0) -> None:
    folder = grid / algo / f"{env.replace('/', '-')}_{seed}"
    folder.mkdir(parents=True)
    record = {
        "spec": {"algo": algo, "env": env, "seed": seed, "n_timesteps": 1_000_000},
        "resumed_at": resumed_at,
        "returncode": returncode,
        "wall_time_s": wall_time_s,
        "host": "vm",
        "code_version": {"commit": ""},
    }
    (folder / "done.json").write_text(json.dumps(record))


def make_grid(root: Path) -> Path:
    grid = root / "grid"
    write_record(grid, "dqn", "MinAtar/Breakout-v0", 40, 1200.0)  # 20 min
    write_record(grid, "dqn", "MinAtar/Breakout-v0", 41, 1800.0)  # 30 min
    write_record(grid, "dqn", "MinAtar/Freeway-v0", 40, 3000.0)  # 50 min
    write_record(grid, "qrdqn", "MinAtar/Breakout-v0", 40, 600.0, resumed_at=[200_000, 800_000])  # 10 min for 200k
    write_record(grid, "qrdqn", "MinAtar/Freeway-v0", 40, 9999.0, returncode=1)  # failed: not a finished run
    return grid


def test_whole_runs_are_summarised_and_resumed_ones_listed_apart(tmp_path: Path):
    rows = run_times.read_records(make_grid(tmp_path))
    assert len(rows) == 4  # the failed run is not read
    summary = run_times.summary_table(rows, split_at=None)
    # dqn: three whole runs of 20, 30 and 50 minutes; qrdqn has no whole run, so no row
    assert summary[2:] == ["| dqn | vm | 3 | 30.0 | 20.0 | 50.0 |"]
    resumed = run_times.resumed_table(rows)
    # the last leg ran from 800,000 to 1,000,000: 10 minutes for 200,000 steps, 5.0 per 100,000
    assert resumed[2:] == ["| qrdqn | MinAtar/Breakout-v0 | 40 | 200,000, 800,000 | 10.0 | 5.0 |"]


def test_split_at_a_commit_this_repository_holds(tmp_path: Path):
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=SCRIPTS).stdout.strip()
    if not head:
        pytest.skip("not a git checkout (an unpacked sdist): nothing to split by")
    assert run_times.contains(head, head) is True
    assert run_times.contains("", head) is None
    row = {"host": "vm", "commit": head}
    assert run_times.group_label(row, head) == f"vm, from {head}"


def test_command_line_writes_the_tables(tmp_path: Path):
    out = tmp_path / "times.md"
    grid = make_grid(tmp_path)
    result = subprocess.run(
        [sys.executable, str(SCRIPTS / "run_times.py"), str(grid), "--out", str(out)], capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
    text = out.read_text()
    assert text.startswith(f"# Run times\n\n`python scripts/run_times.py {grid} --out {out}`")
    assert "4 runs, 3 of them whole" in text
    assert "| dqn | vm | 3 | 30.0 | 20.0 | 50.0 |" in text
    command = [sys.executable, str(SCRIPTS / "run_times.py"), str(tmp_path / "none")]
    empty = subprocess.run(command, capture_output=True, text=True)
    assert empty.returncode == 2 and "no finished runs" in empty.stderr
