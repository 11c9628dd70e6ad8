"""
Issue 27, step 3: does the λ-return choice become OffOnDQN's default? The rule of ``results/headtohead2/README.md``,
stated before any run on seeds 20-29, applied to the finished runs; and the issue's four targets, each met or missed.

The choice (``offon_lambda_choice``) becomes ``OffOnDQN("MlpPolicy", env)``'s default only if, over the ten seeds 20-29:

1. on each of the four tasks the 95% interval of the difference in mean final return (choice - DQN; ``plot.py``'s
   "Against DQN" table) does not lie wholly below zero;
2. its IQM of normalised AUC over the four tasks is above n-step DQN's (point estimates; the four algorithms normalised
   together, as ``plot.py``'s aggregate table does).

The targets do not decide the defaults; they are reported as the issue asks: the IQM of normalised AUC above n-step
DQN's with the intervals apart; the final-return difference to DQN not below zero by its interval on any task and above
on at least two; the IQM of the steps to threshold at most 0.7x DQN's on every task. The fourth target (slippery
FrozenLake-v1 within 2% of DQN's success rate) is measured on the tuning seeds: ``scripts/search.py report``.

Usage::

    python scripts/headtohead2_rule.py                     # results/raw/headtohead2
    python scripts/headtohead2_rule.py --root results/raw --set headtohead2

Prints one line per task, the aggregate, the targets and the verdict: "holds", "does not hold", or "incomplete" while
a cell lacks seeds (the lines are then an interim view, not a decision). Part 1 reads only DQN's and the choice's runs:
once both have all ten seeds on a task and the interval there lies wholly below zero, the rule has failed whatever the
other runs say, and the verdict is "does not hold" before the grid is complete (added 2026-11-26, with no task's
DQN and choice cells complete; the rule is unchanged, only the moment it can be read).
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import run_stats
from search import BENCHMARK_ENVS

BASELINE, NSTEP, CHOICE = "dqn", "dqn_nstep", "offon_lambda_choice"
ALGOS = (BASELINE, NSTEP, "qrdqn", CHOICE)
FRESH_SEEDS = range(20, 30)
STEPS_RATIO_AT_MOST = 0.7
FINAL_ABOVE_AT_LEAST = 2


def judge(runs: dict, scores: dict, reps: int) -> tuple[str, list[str]]:
    """
    The verdict on the defaults, and the lines that show it and the issue's targets.

    :param runs: ``runs[env][algo]``, the fresh runs (``run_stats.Run``), for the aggregate's seeds
    :param scores: ``scores[env][algo]["final" | "auc" | "steps"]``, one value per run in the order of ``runs``
    :param reps: bootstrap resamples of every interval
    :return: ("holds" | "does not hold" | "incomplete", lines)
    """
    lines, complete, failed_for_good = [], True, False
    final_not_below, final_above, steps_ok = 0, 0, 0
    for env in BENCHMARK_ENVS:
        by_algo = scores.get(env, {})
        missing = [algo for algo in ALGOS if len(by_algo.get(algo, {}).get("final", [])) < len(FRESH_SEEDS)]
        complete &= not missing
        if BASELINE not in by_algo or CHOICE not in by_algo:
            lines.append(f"{env}: no runs of {BASELINE if BASELINE not in by_algo else CHOICE} yet")
            continue
        dqn, choice = by_algo[BASELINE], by_algo[CHOICE]
        point, low, high = run_stats.two_sample_ci(choice["final"], dqn["final"], run_stats.mean_difference, reps)
        # Not wholly below zero: a NaN bound (a single run) cannot show it, and the cell is incomplete anyway.
        # Written as `not high < 0` because `high >= 0` is False for NaN and would call one run "below".
        not_below, above = not bool(high < 0), bool(low > 0)
        # Part 1 here depends on these two cells alone: complete and below, no other run can save the rule
        failed_for_good |= not not_below and min(len(choice["final"]), len(dqn["final"])) >= len(FRESH_SEEDS)
        final_not_below += not_below
        final_above += above
        ratio = run_stats.two_sample_ci(choice["steps"], dqn["steps"], run_stats.iqm_ratio, reps)
        steps_ok += ratio[0] <= STEPS_RATIO_AT_MOST
        reading = "above zero" if above else "not below zero" if not_below else "BELOW zero"
        if np.isnan(high):
            reading = "no interval yet"
        lines.append(
            f"{env} ({len(choice['final'])} vs {len(dqn['final'])} seeds"
            + (f"; still to run: {', '.join(missing)}" if missing else "")
            + f"): final return minus DQN's {run_stats.interval_text((point, low, high), '+,.1f')} -> "
            + reading
            + f"; IQM steps to threshold ÷ DQN's {run_stats.interval_text(ratio)}"
        )
    aggregate = run_stats.aggregates(
        {env: {algo: runs[env][algo] for algo in ALGOS if algo in runs[env]} for env in BENCHMARK_ENVS if env in runs},
        scores,
        reps,
    )
    covered = aggregate is not None and aggregate["envs"] == list(BENCHMARK_ENVS) and set(aggregate["algos"]) == set(ALGOS)
    complete &= covered
    faster = apart = False
    if covered:
        choice_auc, nstep_auc = aggregate["iqm_auc"][CHOICE], aggregate["iqm_auc"][NSTEP]
        faster, apart = bool(choice_auc[0] > nstep_auc[0]), bool(choice_auc[1] > nstep_auc[2])
        lines.append(
            f"IQM of normalised AUC over the four tasks: {CHOICE} {run_stats.interval_text(choice_auc)}, "
            f"{NSTEP} {run_stats.interval_text(nstep_auc)}"
        )
    else:
        lines.append("IQM of normalised AUC over the four tasks: waits until every algorithm has its runs on every task")
    tasks = len(BENCHMARK_ENVS)
    lines += [
        f"Rule 1, final return not below DQN's by the interval: {final_not_below} of {tasks} tasks (all needed)",
        # Without the aggregate there is nothing to compare: "no" or "missed" there would read as a result
        f"Rule 2, IQM of normalised AUC above n-step DQN's: {('yes' if faster else 'no') if covered else 'waits'}",
        "Target, that IQM above n-step DQN's with the intervals apart: "
        + (("met" if apart else "missed") if covered else "waits"),
        f"Target, final return not below DQN's on every task and above on at least {FINAL_ABOVE_AT_LEAST}: "
        + ("met" if final_not_below == tasks and final_above >= FINAL_ABOVE_AT_LEAST else "missed")
        + f" (above on {final_above})",
        f"Target, IQM steps to threshold at most {STEPS_RATIO_AT_MOST}x DQN's on every task: "
        + ("met" if steps_ok == tasks else "missed")
        + f" ({steps_ok} of {tasks})",
    ]
    if not complete:
        if failed_for_good:
            lines.append("Rule 1 failed on a task whose DQN and choice runs are all in: the remaining runs cannot change that")
            return "does not hold", lines
        return "incomplete", lines
    return ("holds" if final_not_below == tasks and faster else "does not hold"), lines


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--root", type=Path, default=Path("results/raw"), help="folder of the grids (default: results/raw)")
    parser.add_argument("--set", default="headtohead2", help="the grid's folder under --root (default: headtohead2)")
    parser.add_argument("--reps", type=int, default=2000, help="bootstrap resamples (default: 2000, as plot.py)")
    args = parser.parse_args(argv)
    runs, scores = run_stats.scores_on_seeds(args.root / args.set, ALGOS, FRESH_SEEDS)
    verdict, lines = judge(runs, scores, args.reps)
    print("\n".join(lines))
    print(f"Verdict: {verdict}")
    return verdict


if __name__ == "__main__":
    main()
