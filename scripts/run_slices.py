"""
Run slices of a benchmark grid on a many-core machine for a fixed time, then pack the runs' newest checkpoints to take
them elsewhere, where ``scripts/benchmark.py`` resumes each run from its checkpoint.

A slice is one ``scripts/benchmark.py`` selection (its arguments as one string, for instance ``"--algos dqn --seeds
44-44 --workers 5"``); the slices run side by side from the start, each run on one torch thread and checkpointing every
``--checkpoint-freq`` env steps into ``<root>/.checkpoints/<grid>/<algo>/<env>_<seed>/``. After ``--stop-after`` seconds
the slices still running are stopped (each slice runs in a process group of its own, and only those groups are
signalled: a checkpoint is written in full before it is named the newest, so stopping cannot leave a half-written one).
Then the newest checkpoint of every run (its ``spec.json``, ``latest`` and the checkpoint it names) is compressed into
an archive of its own, the runs that got furthest first, and the archives are gathered into at most ``--bundles``
bundles of at most ``--bundle-bytes`` bytes each and ``--total-bytes`` together, the limits of whatever carries the
files back; a run that does not fit is named in the log and left out. ``unpack`` puts them under a root that
``scripts/benchmark.py --root`` then reads, where the runs go on from their checkpoints (``done.json`` lists the step
each resumed at).

Usage::

    # on the many-core machine, from the repository's root, with the package installed (pip install -e ".[all]")
    python scripts/run_slices.py run --out OUT --stop-after 535 --copy results/raw/minatar \\
        --study benchmarks/minatar.yml "--algos dqn --seeds 44-44 --workers 5" "--algos qrdqn --seeds 43-43 --workers 5"
    # the checkpoints of an earlier stop, packed again
    python scripts/run_slices.py pack --root /tmp/raw --out OUT
    # back home: the runs resume from their checkpoints
    python scripts/run_slices.py unpack OUT/bundle*.tar --root results/raw
    python scripts/benchmark.py --study benchmarks/minatar.yml --workers 2

``OUT/slices.log`` records the machine (CPU, Python and library versions, commit), the slices' commands, when they were
stopped, and the step each run's newest checkpoint had reached, packed or left out; ``OUT/slice<i>.log`` is the
output of slice ``i``.
"""

import argparse
import importlib.metadata
import io
import json
import os
import platform
import shlex
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from dataclasses import dataclass
from pathlib import Path

BENCHMARK = Path(__file__).resolve().parent / "benchmark.py"
LIBRARIES = ("torch", "numpy", "gymnasium", "stable-baselines3", "sb3-contrib", "rl_zoo3", "sb3-offon", "minatar")


@dataclass(frozen=True)
class RunCheckpoint:
    """The newest checkpoint of one run: its folder under the root, the step it reached and the sub-folder holding it."""

    folder: Path
    num_timesteps: int
    step_folder: str


def describe_machine() -> list[str]:
    """What a log should say about the machine and the code: host, CPU, Python, library versions, commit."""
    lines = [f"{time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())} on {platform.node()}"]
    lines.append(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; Python {platform.python_version()}")
    versions = []
    for name in LIBRARIES:
        try:
            versions.append(f"{name} {importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            versions.append(f"{name} absent")
    lines.append(", ".join(versions))
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=False).stdout.strip()
    lines.append(f"commit {commit or 'unknown'}")
    return lines


def benchmark_command(selection: str, study: str | None, root: Path, checkpoint_freq: int) -> list[str]:
    """The ``scripts/benchmark.py`` command of one slice."""
    command = [sys.executable, str(BENCHMARK)] + (["--study", study] if study else []) + shlex.split(selection)
    return [*command, "--root", str(root), "--checkpoint-freq", str(checkpoint_freq)]


def run_for(commands: list[list[str]], seconds: float, logs: Path, poll: float = 1.0) -> list[int | None]:
    """
    Run the commands side by side for at most ``seconds``, each in a process group of its own with its output in
    ``logs/slice<i>.log``; then stop the groups still running (SIGKILL). The return codes, None for those stopped.
    """
    processes = []
    for index, command in enumerate(commands):
        with open(logs / f"slice{index}.log", "wb") as log:
            processes.append(subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, start_new_session=True))
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and any(process.poll() is None for process in processes):
        time.sleep(poll)
    codes: list[int | None] = []
    for process in processes:
        if process.poll() is None:
            try:
                os.killpg(process.pid, signal.SIGKILL)  # the slice's benchmark.py and its training runs, nothing else
            except ProcessLookupError:
                pass  # ended just now
            process.wait()
            codes.append(None)
        else:
            codes.append(process.returncode)
    return codes


def newest_checkpoints(root: Path) -> list[RunCheckpoint]:
    """
    The newest checkpoint of every run under ``root/.checkpoints``, the runs that got furthest first: a grid's runs lie
    in ``<grid>/<algo>/<env>_<seed>/``, a grid being one folder or, for a study's candidate, several
    (``search/<candidate>/tuned``).
    """
    runs = []
    for spec in sorted(root.glob(".checkpoints/**/spec.json")):
        folder = spec.parent
        try:
            step_folder = (folder / "latest").read_text().strip()
            state = json.loads((folder / step_folder / "checkpoint.json").read_text())
        except (OSError, ValueError):
            continue  # started, but no checkpoint written yet
        runs.append(RunCheckpoint(folder.relative_to(root), int(state["num_timesteps"]), step_folder))
    return sorted(runs, key=lambda run: (-run.num_timesteps, str(run.folder)))


def archive(root: Path, run: RunCheckpoint, target: Path, compression: str) -> Path:
    """
    One run's newest checkpoint as ``target/<grid>__<algo>__<env>_<seed>.tar.zst`` (zstd) or ``.tar.xz`` (xz), named
    by its whole folder so that two grids' runs of one algorithm do not collide.
    """
    names = ("spec.json", "latest", run.step_folder)
    plain = target / f"{'__'.join(run.folder.parts[1:])}.tar"
    with tarfile.open(plain, "w") if compression == "zstd" else tarfile.open(f"{plain}.xz", "w:xz", preset=1) as tar:
        for name in names:
            tar.add(root / run.folder / name, arcname=str(run.folder / name))
    if compression == "zstd":
        subprocess.run(["zstd", "-q", "-f", "--rm", "-6", "-T0", "--long=27", str(plain)], check=True)
        return Path(f"{plain}.zst")
    return Path(f"{plain}.xz")


def pack(root: Path, out: Path, bundles: int = 7, bundle_bytes: int = 15_500_000, total_bytes: int = 63_000_000) -> list[str]:
    """
    Pack the newest checkpoint of every run under ``root`` into ``out/bundle<i>.tar`` (first fit, the runs that got
    furthest first) within the limits; the lines say what went into which bundle and what was left out.
    """
    compression = "zstd" if shutil.which("zstd") else "xz"
    scratch = out / ".archives"
    scratch.mkdir(parents=True, exist_ok=True)
    contents: list[list[Path]] = [[] for _ in range(bundles)]
    sizes = [0] * bundles
    lines = []
    for run in newest_checkpoints(root):
        path = archive(root, run, scratch, compression)
        size = path.stat().st_size
        fits = [index for index in range(bundles) if sizes[index] + size <= bundle_bytes]
        if not fits or sum(sizes) + size > total_bytes:
            lines.append(f"LEFT OUT {run.folder} at {run.num_timesteps} steps ({size} bytes)")
            continue
        sizes[fits[0]] += size
        contents[fits[0]].append(path)
        lines.append(f"packed {run.folder} at {run.num_timesteps} steps ({size} bytes) into bundle {fits[0]}")
    for index, paths in enumerate(contents):
        if paths:
            with tarfile.open(out / f"bundle{index}.tar", "w") as tar:
                for path in paths:
                    tar.add(path, arcname=path.name)
    shutil.rmtree(scratch)
    lines.append(f"bundles (bytes): {[size for size in sizes if size]}")
    return lines


def unpack(bundles: list[Path], root: Path) -> list[str]:
    """Put the checkpoints of the bundles under ``root`` (``root/.checkpoints/...``); the runs' folders, as lines."""
    unpacked = []
    for bundle in bundles:
        with tarfile.open(bundle) as outer:
            for member in outer.getmembers():
                data = outer.extractfile(member)
                if data is None:
                    continue
                raw = data.read()
                if member.name.endswith(".zst"):
                    command = ["zstd", "-q", "-d", "-c", "--long=27"]
                    raw = subprocess.run(command, input=raw, capture_output=True, check=True).stdout
                with tarfile.open(fileobj=io.BytesIO(raw)) as inner:
                    inner.extractall(root, filter="data")
                    unpacked.append(str(Path(inner.getnames()[0]).parent))
    return unpacked


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="run slices for a fixed time, then pack their newest checkpoints")
    run.add_argument("selections", nargs="+", help="one scripts/benchmark.py selection per slice, each as one string")
    run.add_argument("--study", default=None, help="the study file every slice runs (passed to scripts/benchmark.py)")
    run.add_argument("--stop-after", type=float, required=True, help="seconds from the start at which to stop the slices")
    run.add_argument("--root", type=Path, default=Path("/tmp/raw"), help="where the runs and their checkpoints go")
    run.add_argument(
        "--copy",
        type=Path,
        action="append",
        default=[],
        help="a grid folder of finished runs to copy into --root (repeatable)",
    )
    run.add_argument("--checkpoint-freq", type=int, default=25_000, help="env steps between checkpoints")
    pack_parser = commands.add_parser("pack", help="pack the newest checkpoints of the runs under --root")
    pack_parser.add_argument("--root", type=Path, default=Path("/tmp/raw"))
    for sub in (run, pack_parser):
        sub.add_argument("--out", type=Path, required=True, help="the folder that goes back: bundles and logs")
        sub.add_argument("--bundles", type=int, default=7, help="at most this many bundles")
        sub.add_argument("--bundle-bytes", type=int, default=15_500_000, help="at most this many bytes a bundle")
        sub.add_argument("--total-bytes", type=int, default=63_000_000, help="at most this many bytes in all")
    unpack_parser = commands.add_parser("unpack", help="put the bundles' checkpoints under --root")
    unpack_parser.add_argument("bundles", type=Path, nargs="+")
    unpack_parser.add_argument("--root", type=Path, default=Path("results/raw"))
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.command == "unpack":
        print("\n".join(unpack(args.bundles, args.root)))
        return
    args.out.mkdir(parents=True, exist_ok=True)
    lines = describe_machine()
    if args.command == "run":
        start = time.monotonic()
        for grid in args.copy:
            shutil.copytree(grid, args.root / grid.name, dirs_exist_ok=True)
        commands = [benchmark_command(selection, args.study, args.root, args.checkpoint_freq) for selection in args.selections]
        lines += [shlex.join(command) for command in commands]
        codes = run_for(commands, args.stop_after - (time.monotonic() - start), args.out)
        lines.append(f"stopped at {time.monotonic() - start:.0f} s; return codes (None: stopped): {codes}")
    lines += pack(args.root, args.out, args.bundles, args.bundle_bytes, args.total_bytes)
    (args.out / "slices.log").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
