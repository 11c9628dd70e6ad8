"""
The Results table of ``docs/offon_dqn.md``: mean ± standard deviation over seeds, per env and algorithm.

Reads the finished runs that ``scripts/benchmark.py`` wrote under ``<root>/<set>/<algo>/<env>_<seed>/``
(``done.json``: the run's spec and return code; ``evaluations.npz``: ``timesteps`` and ``results``, the returns of
the deterministic policy at each periodic evaluation) and prints a markdown table, one column per algorithm.

Per run:

- the evaluation curve: the mean return of each evaluation, put on the env's grid of evaluation steps (the union over
  its runs; a run that stopped early, by the CartPoleFallPenalty-v1 stop rule, keeps its last value, as in
  ``scripts/plot.py``);
- **final**: the return of the last evaluation (``scripts/plot.py``'s "final return" is the mean of the last 3);
- **AUC**: the area under the evaluation curve divided by its span in env steps, i.e. the mean evaluation return over
  training (``scripts/plot.py``'s AUC).

Then the mean ± standard deviation over seeds (sample standard deviation, ``ddof=1``).

Usage::

    python scripts/docs_table.py --root results/raw --set tuned
"""

import argparse
import json
from pathlib import Path

import numpy as np

ALGOS = ["offon_dqn", "dqn_mc", "dqn_sarsa", "dqn"]
LABELS = {"offon_dqn": "Off-On DQN", "dqn_mc": "DQN with MC", "dqn_sarsa": "DQN with Sarsa", "dqn": "DQN"}


def load_runs(folder: Path) -> dict[str, dict[str, list[dict]]]:
    """``runs[env][algo]``: the finished runs (return code 0, every evaluation present), by seed."""
    runs: dict[str, dict[str, list[dict]]] = {}
    for done in sorted(folder.glob("*/*/done.json")):
        record = json.loads(done.read_text())
        with np.load(done.parent / "evaluations.npz") as data:
            timesteps, results = data["timesteps"], data["results"]
        if record.get("returncode") != 0 or len(timesteps) != record.get("n_evaluations"):
            continue
        spec = record["spec"]
        run = {"seed": spec["seed"], "budget": spec["n_timesteps"], "timesteps": timesteps, "returns": results.mean(axis=1)}
        runs.setdefault(spec["env"], {}).setdefault(spec["algo"], []).append(run)
    for by_algo in runs.values():
        for algo_runs in by_algo.values():
            algo_runs.sort(key=lambda run: run["seed"])
    return runs


def mean_std(values: np.ndarray) -> str:
    if len(values) == 1:
        return f"{values[0]:.1f}"
    return f"{np.mean(values):.1f} ± {np.std(values, ddof=1):.1f}"


def seeds_text(seed_lists: list[list[int]]) -> str:
    """A range ("0-9") when every algorithm has the same contiguous seeds; otherwise each algorithm's seed count."""
    seeds = seed_lists[0]
    if all(other == seeds for other in seed_lists) and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else str(seeds[0])
    return "/".join(str(len(other)) for other in seed_lists)


def table(root: Path, hyperparams_set: str, algos: list[str] = ALGOS) -> str:
    runs = load_runs(root / hyperparams_set)
    header = ["Env", "Budget", "Seeds", "Metric", *(LABELS.get(algo, algo) for algo in algos)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * 3 + "---|" + "---:|" * len(algos)]
    for env in sorted(runs):
        by_algo = {algo: runs[env].get(algo, []) for algo in algos}
        present = [algo_runs for algo_runs in by_algo.values() if algo_runs]
        grid = np.unique(np.concatenate([run["timesteps"] for algo_runs in present for run in algo_runs]))
        cells: dict[str, list[str]] = {"final": [], "AUC": []}
        for algo_runs in by_algo.values():
            if not algo_runs:
                cells["final"].append("n/a")
                cells["AUC"].append("n/a")
                continue
            curves = np.stack([np.interp(grid, run["timesteps"], run["returns"]) for run in algo_runs])
            auc = np.trapezoid(curves, grid, axis=1) / (grid[-1] - grid[0]) if len(grid) > 1 else curves[:, 0]
            cells["final"].append(mean_std(curves[:, -1]))
            cells["AUC"].append(mean_std(auc))
        budgets = sorted({run["budget"] for algo_runs in present for run in algo_runs})
        budget = "/".join(f"{value:,}" for value in budgets)
        seeds = seeds_text([[run["seed"] for run in algo_runs] for algo_runs in present])
        for metric, values in cells.items():
            lines.append("| " + " | ".join([env, budget, seeds, metric, *values]) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=Path("results/raw"), help="results root (default: results/raw)")
    parser.add_argument("--set", default="tuned", help="hyperparameter set, a folder of the root (default: tuned)")
    parser.add_argument("--algos", nargs="+", default=ALGOS, help=f"columns (default: {' '.join(ALGOS)})")
    args = parser.parse_args()
    print(table(args.root, args.set, args.algos))
