"""scripts/run_slices.py: slices stopped on time with the processes they started, and the newest checkpoints packed."""

import json
import os
import shutil
import sys
import time
from pathlib import Path

import pytest
from helpers import load_script

run_slices = load_script("run_slices")


def fake_run(root: Path, algo: str, run: str, steps: list[int], size: int, grid: str = "grid") -> Path:
    """A run's checkpoint folder as scripts/benchmark.py leaves it: spec.json, ``latest`` and a folder per checkpoint."""
    folder = root / ".checkpoints" / grid / algo / run
    folder.mkdir(parents=True)
    (folder / "spec.json").write_text(json.dumps({"algo": algo}))
    for step in steps:
        (folder / str(step)).mkdir()
        (folder / str(step) / "checkpoint.json").write_text(json.dumps({"num_timesteps": step}))
        (folder / str(step) / "replay_buffer.pkl").write_bytes(os.urandom(size))  # random: it does not compress
    (folder / "latest").write_text(f"{steps[-1]}\n")
    return folder


@pytest.mark.parametrize("compression", ["zstd", "xz"])
def test_the_newest_checkpoints_are_packed_furthest_first_within_the_limits(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compression: str
) -> None:
    if compression == "zstd" and shutil.which("zstd") is None:
        pytest.skip("no zstd on this machine")
    if compression == "xz":
        monkeypatch.setattr(run_slices.shutil, "which", lambda name: None)
    root, out = tmp_path / "raw", tmp_path / "out"
    fake_run(root, "dqn", "MinAtar-Breakout-v0_40", [25_000, 50_000], 30_000)
    fake_run(root, "qrdqn", "MinAtar-Breakout-v0_40", [75_000], 30_000)
    fake_run(root, "qrdqn", "MinAtar-Freeway-v0_41", [25_000], 30_000)  # the least far: left out
    started = root / ".checkpoints" / "grid" / "dqn" / "MinAtar-Seaquest-v0_40"
    started.mkdir(parents=True)
    (started / "spec.json").write_text("{}")  # started, no checkpoint yet: nothing to pack
    out.mkdir()

    lines = run_slices.pack(root, out, bundles=2, bundle_bytes=40_000, total_bytes=70_000)

    assert lines[0].startswith("packed .checkpoints/grid/qrdqn/MinAtar-Breakout-v0_40 at 75000 steps")
    assert lines[0].endswith("into bundle 0")
    assert lines[1].startswith("packed .checkpoints/grid/dqn/MinAtar-Breakout-v0_40 at 50000 steps")
    assert lines[1].endswith("into bundle 1")
    assert lines[2].startswith("LEFT OUT .checkpoints/grid/qrdqn/MinAtar-Freeway-v0_41 at 25000 steps")
    assert sorted(path.name for path in out.iterdir()) == ["bundle0.tar", "bundle1.tar"]

    home = tmp_path / "home"
    unpacked = run_slices.unpack(sorted(out.glob("bundle*.tar")), home)
    assert sorted(unpacked) == [
        ".checkpoints/grid/dqn/MinAtar-Breakout-v0_40",
        ".checkpoints/grid/qrdqn/MinAtar-Breakout-v0_40",
    ]
    for run, step in (("dqn/MinAtar-Breakout-v0_40", "50000"), ("qrdqn/MinAtar-Breakout-v0_40", "75000")):
        source, copy = root / ".checkpoints" / "grid" / run, home / ".checkpoints" / "grid" / run
        assert sorted(path.name for path in copy.iterdir()) == sorted(["spec.json", "latest", step])  # the newest only
        for name in ("spec.json", "latest", f"{step}/checkpoint.json", f"{step}/replay_buffer.pkl"):
            assert (copy / name).read_bytes() == (source / name).read_bytes(), name


def alive(pid: int) -> bool:
    """Whether a process runs (a zombie, ended and not yet reaped, does not)."""
    try:
        return "\nState:\tZ" not in Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_slices_are_stopped_on_time_with_the_processes_they_started(tmp_path: Path) -> None:
    # A slice that starts a child of its own (as benchmark.py starts training runs), and one that ends by itself
    child = "import subprocess, sys, time; p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])"
    waits = [sys.executable, "-c", f"{child}; print(p.pid, flush=True); time.sleep(60)"]
    ends = [sys.executable, "-c", "print('done')"]
    start = time.monotonic()
    codes = run_slices.run_for([waits, ends], seconds=3, logs=tmp_path, poll=0.1)
    assert time.monotonic() - start < 30
    assert codes == [None, 0]
    assert (tmp_path / "slice1.log").read_text() == "done\n"
    grandchild = int((tmp_path / "slice0.log").read_text())
    deadline = time.monotonic() + 10
    while alive(grandchild) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not alive(grandchild)


def test_each_slice_is_a_benchmark_command_with_the_root_and_checkpoints(tmp_path: Path) -> None:
    options = [
        "--out",
        str(tmp_path),
        "--stop-after",
        "535",
        "--copy",
        "results/raw/minatar",
        "--study",
        "benchmarks/minatar.yml",
    ]
    args = run_slices.parse_args(["run", *options, "--algos dqn --seeds 44-44 --workers 5", "--algos qrdqn --seeds 43-43"])
    assert args.copy == [Path("results/raw/minatar")] and len(args.selections) == 2
    command = run_slices.benchmark_command(args.selections[0], args.study, Path("/tmp/raw"), args.checkpoint_freq)
    assert command[1:] == [
        str(run_slices.BENCHMARK),
        *("--study", "benchmarks/minatar.yml", "--algos", "dqn", "--seeds", "44-44", "--workers", "5"),
        *("--root", "/tmp/raw", "--checkpoint-freq", "25000"),
    ]


def test_the_runs_of_a_candidates_nested_grid_are_packed_apart(tmp_path: Path) -> None:
    """A study's candidates run in grids of several folders (``search/<candidate>/tuned``), two of them with the same
    algorithm: each run is packed, under its own name, and unpacked where it was."""
    root, out = tmp_path / "raw", tmp_path / "out"
    for candidate in ("cache", "no_cache"):
        fake_run(root, "offon_qrdqn", "MinAtar-Asterix-v0_1", [50_000], 1_000, grid=f"search/horizon_{candidate}/tuned")
    out.mkdir()
    lines = run_slices.pack(root, out)
    assert [line.split(" at ")[0] for line in lines[:2]] == [
        "packed .checkpoints/search/horizon_cache/tuned/offon_qrdqn/MinAtar-Asterix-v0_1",
        "packed .checkpoints/search/horizon_no_cache/tuned/offon_qrdqn/MinAtar-Asterix-v0_1",
    ]
    unpacked = run_slices.unpack(sorted(out.glob("bundle*.tar")), tmp_path / "home")
    assert sorted(unpacked) == [
        ".checkpoints/search/horizon_cache/tuned/offon_qrdqn/MinAtar-Asterix-v0_1",
        ".checkpoints/search/horizon_no_cache/tuned/offon_qrdqn/MinAtar-Asterix-v0_1",
    ]
