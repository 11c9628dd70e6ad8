"""
How long the runs of a grid took: wall-clock minutes per algorithm, read from each finished run's ``done.json``
(``scripts/benchmark.py`` writes it; its ``wall_time_s`` is the time of the run's last start only).

A run that resumed from a checkpoint (``resumed_at`` not empty) did only part of its steps in that time: it is listed
apart and left out of the whole-run figures. ``--split-at COMMIT`` groups the whole runs by whether the code they ran
(``code_version.commit``) contains that commit (``git merge-base --is-ancestor``), to set runs before and after a change
side by side; these are observations of runs made under whatever else the machine did, not a controlled comparison.

Usage::

    python scripts/run_times.py results/raw/minatar
    python scripts/run_times.py results/raw/minatar --split-at 38cd2a5 --out results/minatar/run_times.md
"""

import argparse
import functools
import json
import statistics
import subprocess
import sys
from pathlib import Path

# The other scripts sit next to this one: importable however it is started
sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_records import DONE


def read_records(grid: Path) -> list[dict]:
    """One row per finished run under ``grid`` (``<grid>/<algo>/<env>_<seed>/done.json``, return code 0)."""
    rows = []
    for path in sorted(grid.glob(f"*/*/{DONE}")):
        record = json.loads(path.read_text())
        if record.get("returncode") != 0:
            continue
        spec = record["spec"]
        rows.append(
            {
                "algo": path.parent.parent.name,
                "env": spec["env"],
                "seed": spec["seed"],
                "minutes": record["wall_time_s"] / 60,
                "n_timesteps": spec["n_timesteps"],
                "resumed_at": record.get("resumed_at") or [],
                "host": record.get("host", "?"),
                "commit": (record.get("code_version") or {}).get("commit") or "",
            }
        )
    return rows


@functools.cache  # many runs share a commit: one git call for each
def contains(commit: str, ancestor: str) -> bool | None:
    """Whether ``commit`` contains ``ancestor`` in this repository's history; None when git cannot tell."""
    if not commit:
        return None
    command = ["git", "merge-base", "--is-ancestor", ancestor, commit]
    result = subprocess.run(command, capture_output=True, cwd=Path(__file__).resolve().parent)
    return {0: True, 1: False}.get(result.returncode)


def group_label(row: dict, split_at: str | None) -> str:
    """The group a whole run is summarised in: its host, and with ``split_at`` which side of that commit it ran."""
    if split_at is None:
        return row["host"]
    side = {True: f"from {split_at}", False: f"before {split_at}", None: "commit unknown"}[contains(row["commit"], split_at)]
    return f"{row['host']}, {side}"


def summary_table(rows: list[dict], split_at: str | None) -> list[str]:
    """Whole runs (never resumed): count, median, min and max minutes per algorithm and group."""
    groups: dict[tuple[str, str], list[float]] = {}
    for row in rows:
        if not row["resumed_at"]:
            groups.setdefault((row["algo"], group_label(row, split_at)), []).append(row["minutes"])
    lines = ["| algorithm | runs on | whole runs | median min | min | max |", "|---|---|---:|---:|---:|---:|"]
    for (algo, label), minutes in sorted(groups.items()):
        spread = f"{statistics.median(minutes):.1f} | {min(minutes):.1f} | {max(minutes):.1f}"
        lines.append(f"| {algo} | {label} | {len(minutes)} | {spread} |")
    return lines


def resumed_table(rows: list[dict]) -> list[str]:
    """
    Runs that went on from a checkpoint: the steps they resumed at, the minutes of their last leg (from the last resume
    to the budget) and those minutes per 100,000 of its steps.
    """
    lines = [
        "| algorithm | env | seed | resumed at | minutes of the last leg | per 100k steps |",
        "|---|---|---:|---|---:|---:|",
    ]
    for row in rows:
        if row["resumed_at"]:
            steps = ", ".join(f"{step:,}" for step in row["resumed_at"])
            per_100k = row["minutes"] / ((row["n_timesteps"] - row["resumed_at"][-1]) / 100_000)
            lines.append(f"| {row['algo']} | {row['env']} | {row['seed']} | {steps} | {row['minutes']:.1f} | {per_100k:.1f} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("grid", type=Path, help="a grid's folder of runs, e.g. results/raw/minatar")
    parser.add_argument("--split-at", help="a commit: group whole runs by whether their code contains it")
    parser.add_argument("--out", type=Path, help="write the tables to this Markdown file too")
    args = parser.parse_args()

    rows = read_records(args.grid)
    if not rows:
        parser.error(f"no finished runs (done.json) under {args.grid}")
    whole = sum(not row["resumed_at"] for row in rows)
    text = [
        f"Wall-clock minutes of the finished runs under `{args.grid}` (`done.json`'s `wall_time_s`): {len(rows)} runs, "
        f"{whole} of them whole (never resumed).",
        "",
        *summary_table(rows, args.split_at),
        "",
        "Resumed runs (left out above):",
        "",
        *resumed_table(rows),
    ]
    print("\n".join(text))
    if args.out:
        command = " ".join(["python scripts/run_times.py", *sys.argv[1:]])
        args.out.write_text("\n".join(["# Run times", "", f"`{command}`", "", *text]) + "\n")


if __name__ == "__main__":
    main()
