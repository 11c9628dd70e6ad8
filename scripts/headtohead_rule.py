"""
Issue 13, step 6: does the search's choice hold on the head-to-head's fresh seeds? The rule of
``results/headtohead/README.md``, stated before the runs it judges, applied to the finished runs.

``offon_choice``'s target settings become OffOnDQN's defaults only if, over the ten seeds 10-19:

1. on each of the four tasks its mean final return (mean of the last three evaluations) is at least DQN's minus 2% of
   the task's range: the search's own bar (``scripts/search.py``'s ``bar``);
2. its AUC lies above DQN's with the two 95% intervals apart on at least three of the four tasks (the intervals of
   ``scripts/plot.py``'s tables and of its "Against DQN" verdict).

Usage::

    python scripts/headtohead_rule.py                      # results/raw/headtohead
    python scripts/headtohead_rule.py --root results/raw --set headtohead

Prints one line per task and the verdict: "holds", "does not hold", or "incomplete" while a task lacks seeds (the
lines are then an interim view, not a decision).
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import run_stats
import search

BASELINE = "dqn"
CHOICE = "offon_choice"
FRESH_SEEDS = range(10, 20)
SEEDS = len(FRESH_SEEDS)
AUC_APART_AT_LEAST = 3


def judge(scores: dict[str, dict[str, dict[str, np.ndarray]]], reps: int) -> tuple[str, list[str]]:
    """
    The verdict and one line per task, from ``scores[env][algo]["final" | "auc"]`` (one value per seed).

    :param scores: per task and algorithm, the per-seed final returns and AUCs (``run_stats.run_scores``'s fields)
    :param reps: bootstrap resamples of the AUC intervals
    :return: ("holds" | "does not hold" | "incomplete", lines)
    """
    lines, final_ok, auc_apart, complete = [], 0, 0, True
    for env in search.BENCHMARK_ENVS:
        by_algo = scores.get(env, {})
        if BASELINE not in by_algo or CHOICE not in by_algo:
            lines.append(f"{env}: no runs of {BASELINE if BASELINE not in by_algo else CHOICE} yet")
            complete = False
            continue
        dqn, choice = by_algo[BASELINE], by_algo[CHOICE]
        complete &= min(len(dqn["final"]), len(choice["final"])) >= SEEDS
        bar = search.bar(env, float(np.mean(dqn["final"])))
        final = float(np.mean(choice["final"]))
        final_ok += final >= bar
        dqn_auc, choice_auc = run_stats.mean_interval(dqn["auc"], reps), run_stats.mean_interval(choice["auc"], reps)
        apart = run_stats.position(choice_auc, dqn_auc) == "above, apart"
        auc_apart += apart
        lines.append(
            f"{env} ({len(choice['final'])} vs {len(dqn['final'])} seeds): final {final:.1f} against the bar {bar:.1f} "
            f"(DQN {np.mean(dqn['final']):.1f}) -> {'ok' if final >= bar else 'BELOW'}; "
            f"AUC [{choice_auc[0]:.1f}, {choice_auc[1]:.1f}] against DQN's [{dqn_auc[0]:.1f}, {dqn_auc[1]:.1f}] -> "
            f"{'above, apart' if apart else 'not apart above'}"
        )
    lines.append(
        f"Final return at or above the bar on {final_ok} of {len(search.BENCHMARK_ENVS)} tasks (all needed); "
        f"AUC above DQN's and apart on {auc_apart} (at least {AUC_APART_AT_LEAST} needed)"
    )
    if not complete:
        return "incomplete", lines
    holds = final_ok == len(search.BENCHMARK_ENVS) and auc_apart >= AUC_APART_AT_LEAST
    return ("holds" if holds else "does not hold"), lines


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--root", type=Path, default=Path("results/raw"), help="folder of the grids (default: results/raw)")
    parser.add_argument("--set", default="headtohead", help="the grid's folder under --root (default: headtohead)")
    parser.add_argument("--reps", type=int, default=2000, help="bootstrap resamples (default: 2000, as plot.py)")
    args = parser.parse_args(argv)
    _, scores = run_stats.scores_on_seeds(args.root / args.set, (BASELINE, CHOICE), FRESH_SEEDS)
    verdict, lines = judge(scores, args.reps)
    print("\n".join(lines))
    print(f"Verdict: {verdict}")
    return verdict


if __name__ == "__main__":
    main()
