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

Part 2 can be read early too, in one case (added 2026-11-26, ninth session, while QR-DQN's LunarLander-v3 runs, about
3 h each on this VM, were still to come): when DQN's, n-step DQN's and the choice's runs are all in and the runs still
missing are another algorithm's on one task. Those runs enter part 2 only through that task's min-max normalisation,
which they can only widen; ``auc_gap_bounds`` bounds the choice's IQM minus n-step DQN's over every normalisation they
could produce. If the bounds are both above zero (or both below), no run still to come can change the answer.

The target of the intervals is read early in the same case (added 2026-11-26, tenth session, with the verdict already
read and eight of QR-DQN's runs still to come): ``apart_margins`` computes the two 95% bounds as the complete grid's
aggregate will (rliable's resamples depend on the grid's shape alone, so they can be drawn now) for each place the
present range can take in a widened one, and ``auc_apart_bounds`` bounds them over all places.
"""

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parent))
import run_stats
from search import BENCHMARK_ENVS

BASELINE, NSTEP, CHOICE = "dqn", "dqn_nstep", "offon_lambda_choice"
ALGOS = (BASELINE, NSTEP, "qrdqn", CHOICE)
FRESH_SEEDS = range(20, 30)
STEPS_RATIO_AT_MOST = 0.7
FINAL_ABOVE_AT_LEAST = 2
# The grid of auc_gap_bounds: positions of the open task's present AUC range in a widened one, this far apart
GAP_GRID_STEP = 0.002
# The grid of auc_apart_bounds (a bootstrap at each point: coarser)
APART_GRID_STEP = 0.01


def pooled_iqm(columns: np.ndarray) -> np.ndarray:
    """rliable's IQM (``metrics.aggregate_iqm``: SciPy's 25% trimmed mean of all scores) of each row of ``columns``."""
    return stats.trim_mean(columns, 0.25, axis=-1)


def place_grid(step: float) -> tuple[np.ndarray, np.ndarray]:
    """Every pair of places 0 <= p <= q <= 1 on a grid ``step`` apart (its inverse a whole number)."""
    places = np.linspace(0.0, 1.0, round(1 / step) + 1)
    p, q = (grid.ravel() for grid in np.meshgrid(places, places, indexing="ij"))
    return p[p <= q], q[p <= q]


def moved(values: np.ndarray, column: int, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``values`` (..., tasks) once for each (p, q), its ``column`` (normalised scores y) moved to p + (q - p) * y."""
    shape = (len(p),) + (1,) * (values.ndim - 1)
    result = np.repeat(values[None], len(p), axis=0)
    result[..., column] = p.reshape(shape) + (q - p).reshape(shape) * values[None, ..., column]
    return result


def normalised_auc(runs: dict, scores: dict, open_env: str) -> tuple[dict[str, np.ndarray], int]:
    """
    The (runs, tasks) matrices of normalised AUC that ``run_stats.aggregates`` will read once ``open_env``'s runs are
    all in, as they are before those runs widen its range (``stand_ins``), and the column of ``open_env`` in them.
    """
    runs, scores = stand_ins(runs, scores, open_env)
    envs, _, algos = run_stats.aggregate_cells(runs)
    return run_stats.normalised_matrices(runs, scores, envs, algos)["auc"], envs.index(open_env)


def slack(matrix: np.ndarray, step: float) -> float:
    """
    How far an IQM of the scores of ``matrix`` (runs, tasks) can move when one task's scores each move by at most
    step / 2: sorting does not lengthen the sum of the moves, so by at most (runs / the size of the middle half) * step / 2.
    """
    n_pooled = matrix.size
    return len(matrix) / (n_pooled - 2 * int(0.25 * n_pooled)) * step / 2


def auc_gap_bounds(runs: dict, scores: dict, open_env: str, step: float = GAP_GRID_STEP) -> tuple[float, float]:
    """
    Bounds on the choice's IQM of normalised AUC minus n-step DQN's over every normalisation of ``open_env`` that runs
    still to come there could produce (the other tasks' being final, and both algorithms' runs all in).

    Runs to come can only widen ``open_env``'s AUC range [low, high] (the minimum and maximum over every run there) to
    [low', high']. In it the present normalised scores y (in [0, 1]) become p + (q - p) * y, where p and q, the places
    of low and high, can be any 0 <= p <= q <= 1 (p = q is the limit of a range that new runs widen without bound).
    The gap is computed on a grid of (p, q) ``step`` apart. Every (p, q) lies within step / 2 of a grid point in each
    coordinate, which moves each normalised score of the task by at most step / 2, and each algorithm's IQM by at most
    ``slack``. The grid's extremes widened by that much for both algorithms therefore bound the gap over the whole
    triangle.

    :param runs: ``runs[env][algo]``, the fresh runs
    :param scores: ``scores[env][algo]["auc"]``, in the order of ``runs``; every algorithm on an env counts in its range
    :param open_env: the task whose runs are not all in
    :param step: the grid step (its inverse a whole number)
    :return: (lowest, highest) possible gap
    """
    matrices, column = normalised_auc(runs, scores, open_env)
    p, q = place_grid(step)
    iqm = {algo: pooled_iqm(moved(matrices[algo], column, p, q).reshape(len(p), -1)) for algo in (CHOICE, NSTEP)}
    gap, widening = iqm[CHOICE] - iqm[NSTEP], slack(matrices[CHOICE], step) + slack(matrices[NSTEP], step)
    return float(gap.min() - widening), float(gap.max() + widening)


def stand_ins(runs: dict, scores: dict, open_env: str) -> tuple[dict, dict]:
    """
    ``runs`` and ``scores`` with every missing run on ``open_env`` stood in for by a copy of that algorithm's first run
    there: inside the task's present range, so no normalisation moves, and the grid has the shape it will have complete.
    """
    runs = {env: dict(by_algo) for env, by_algo in runs.items()}
    scores = {env: dict(by_algo) for env, by_algo in scores.items()}
    for algo, present in runs[open_env].items():
        missing = sorted(set(FRESH_SEEDS) - {run.seed for run in present})
        runs[open_env][algo] = present + [dataclasses.replace(present[0], seed=seed) for seed in missing]
        scores[open_env][algo] = {
            key: np.concatenate([values, np.full(len(missing), values[0])]) for key, values in scores[open_env][algo].items()
        }
    return runs, scores


def drawn_resamples(matrices: dict[str, np.ndarray], reps: int) -> dict[str, np.ndarray]:
    """
    The resamples that ``run_stats.interval_estimates`` draws for each algorithm of ``matrices`` (runs, tasks), as run
    indices (reps, runs, tasks): recorded from a call on matrices of codes. rliable draws them from NumPy's global RNG,
    seeded before the call, so they depend on the shapes and the order of the algorithms alone, not on the scores.
    """
    seen = []

    def record(resample: np.ndarray) -> np.ndarray:
        seen.append(np.array(resample))
        return np.zeros(1)

    size = max(len(matrix) for matrix in matrices.values())
    codes = {
        algo: np.broadcast_to(np.arange(len(m))[:, None] + k * size, m.shape).astype(float)
        for k, (algo, m) in enumerate(matrices.items())
    }
    run_stats.interval_estimates(codes, record, reps)
    drawn = {}
    for k, algo in enumerate(matrices):
        # The calls on this algorithm's codes: rliable's point estimate and arch's, on the codes as they are, then the
        # resamples. Another count means another rliable or arch: better to stop than to read the wrong calls.
        mine = [resample for resample in seen if resample.min() >= k * size and resample.max() < (k + 1) * size]
        assert len(mine) == reps + 2 and np.array_equal(mine[0], codes[algo]), (len(mine), reps)
        drawn[algo] = (np.stack(mine[-reps:]) - k * size).astype(int)
    return drawn


def apart_margins(matrices: dict[str, np.ndarray], column: int, reps: int, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """
    The choice's lower 95% bound of the IQM of normalised AUC minus n-step DQN's upper bound (the target's "intervals
    apart": above zero), as ``run_stats.aggregates`` will compute them once the open task's runs are all in, if those
    runs widen its AUC range so that the present one sits at [p, q] of it (one value per pair): the same resamples
    (``drawn_resamples``, on the complete grid's shapes), the same IQM and the same percentiles.

    :param matrices: the normalised AUC of every algorithm, (runs, tasks), as ``normalised_auc`` gives them
    :param column: the task whose runs are not all in (``normalised_auc``'s column)
    :param reps: bootstrap resamples, as the aggregate will use
    :param p: places of the present minimum in the widened range
    :param q: places of the present maximum (p <= q)
    """
    resamples = drawn_resamples(matrices, reps)
    # arch's percentiles of rliable's 95% interval
    tail = 100 * (1 - 0.95) / 2
    bounds = {}
    for algo, percentile in ((CHOICE, tail), (NSTEP, 100 - tail)):
        matrix = matrices[algo]
        resampled = matrix[resamples[algo], np.arange(matrix.shape[1])]  # (reps, runs, tasks)
        ends = []
        for start in range(0, len(p), 64):
            chunk = moved(resampled, column, p[start : start + 64], q[start : start + 64])
            ends.append(np.percentile(pooled_iqm(chunk.reshape(*chunk.shape[:2], -1)), percentile, axis=-1))
        bounds[algo] = np.concatenate(ends)
    return bounds[CHOICE] - bounds[NSTEP]


def auc_apart_bounds(runs: dict, scores: dict, open_env: str, reps: int, step: float = APART_GRID_STEP) -> tuple[float, float]:
    """
    Bounds on ``apart_margins`` over every normalisation of ``open_env`` that runs still to come could produce: its
    values on a grid of (p, q), as ``auc_gap_bounds``, widened by how far they can move between grid points: each
    resample's IQM by at most ``slack``, and so each percentile of them (a percentile moves no further than the values
    it is read from), for each of the two bounds.

    :param runs: ``runs[env][algo]``, the fresh runs
    :param scores: ``scores[env][algo]["auc"]``, in the order of ``runs``
    :param open_env: the task whose runs are not all in
    :param reps: bootstrap resamples, as the aggregate will use
    :param step: the grid step (its inverse a whole number)
    :return: (lowest, highest) possible margin
    """
    matrices, column = normalised_auc(runs, scores, open_env)
    margins = apart_margins(matrices, column, reps, *place_grid(step))
    widening = slack(matrices[CHOICE], step) + slack(matrices[NSTEP], step)
    return float(margins.min() - widening), float(margins.max() + widening)


def open_task(scores: dict) -> str | None:
    """
    The one task where runs are missing, if DQN's, n-step DQN's and the choice's are all in everywhere and the missing
    runs are another algorithm's on that task alone (then part 2 can be bounded, ``auc_gap_bounds``); else None.
    """
    complete = len(FRESH_SEEDS)
    if any(
        len(scores.get(env, {}).get(algo, {}).get("auc", [])) < complete
        for env in BENCHMARK_ENVS
        for algo in (BASELINE, NSTEP, CHOICE)
    ):
        return None
    open_envs = [
        env for env in BENCHMARK_ENVS if any(len(scores[env].get(algo, {}).get("auc", [])) < complete for algo in ALGOS)
    ]
    return open_envs[0] if len(open_envs) == 1 else None


def judge(runs: dict, scores: dict, reps: int, apart_step: float = APART_GRID_STEP) -> tuple[str, list[str]]:
    """
    The verdict on the defaults, and the lines that show it and the issue's targets.

    :param runs: ``runs[env][algo]``, the fresh runs (``run_stats.Run``), for the aggregate's seeds
    :param scores: ``scores[env][algo]["final" | "auc" | "steps"]``, one value per run in the order of ``runs``
    :param reps: bootstrap resamples of every interval
    :param apart_step: the grid step of ``auc_apart_bounds`` when the target is read early
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
    # Part 2 and the target of the intervals read before the grid is complete (see the module's docstring):
    # (task, lowest, highest) of the gap and of the margin between the intervals, or None
    early = early_apart = None
    open_env = None if complete or failed_for_good else open_task(scores)
    if open_env is not None:
        early = (open_env, *auc_gap_bounds(runs, scores, open_env))
        early_apart = (open_env, *auc_apart_bounds(runs, scores, open_env, reps, apart_step))
    early_decided = early is not None and (early[1] > 0 or early[2] < 0)
    apart_early = None if early_apart is None else "met" if early_apart[1] > 0 else "missed" if early_apart[2] < 0 else None
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
        "Rule 2, IQM of normalised AUC above n-step DQN's: "
        + (("yes" if faster else "no") if covered else "waits" if not early_decided else "decided early (below)"),
        "Target, that IQM above n-step DQN's with the intervals apart: "
        + (("met" if apart else "missed") if covered else f"{apart_early}, decided early (below)" if apart_early else "waits"),
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
        if early is None:
            return "incomplete", lines
        env, low, high = early
        lines.append(
            f"Rule 2 before {env}'s last runs: {CHOICE}'s IQM of normalised AUC minus {NSTEP}'s lies in "
            f"[{low:+.4f}, {high:+.4f}] over every normalisation of {env} those runs could produce"
        )
        if early_apart is not None:
            lines.append(
                f"Target of the intervals before {env}'s last runs: the lower 95% bound of {CHOICE}'s IQM minus the "
                f"upper bound of {NSTEP}'s lies in [{early_apart[1]:+.4f}, {early_apart[2]:+.4f}] (apart when above zero)"
            )
        if early_decided:
            lines.append(f"Rules 1 and 2 are decided: the runs still missing on {env} cannot change the verdict")
            return ("holds" if final_not_below == tasks and low > 0 else "does not hold"), lines
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
