"""
The runs of a benchmark and their statistics, shared by ``scripts/plot.py``, ``scripts/study.py`` and ``scripts/selection.py``.

- Loading: every finished run (``done.json``) under ``<root>/<set>/<algo>/<env>_<seed>/``, with its evaluation curve
  and its training episodes (the monitor CSVs);
- per run: final return (mean of the last evaluations), AUC (mean return over training), steps to the threshold;
- intervals: means over seeds with a 95% stratified-bootstrap CI from rliable (seeded, so the same data give the same
  intervals), and two-sample percentile bootstraps (SciPy) of a difference or a ratio between two algorithms;
- aggregates across envs (rliable): IQM of min-max normalised scores and the probability of improvement over DQN.

The definitions are written out in ``scripts/plot.py``'s docstring, which reports them.
"""

import json
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from rliable import library as rly
from rliable import metrics
from scipy import stats

# arch (rliable's bootstrap) warns that ``random_state`` will change meaning; rliable passes it
warnings.filterwarnings("ignore", category=FutureWarning, module="arch")

# The paper's four variants first, in this order, in every table and figure; other algorithms after them by name
ALGOS = ["offon_paper", "dqn_mc", "dqn_sarsa", "dqn"]
# Labels of the command-line names (sb3_offon.zoo.ALGOS), the former names included: the studies' runs carry them
LABELS = {
    "offon_paper": "Off-On DQN",
    "dqn_mc": "DQN with MC",
    "dqn_sarsa": "DQN with Sarsa",
    "dqn": "DQN",
    "dqn_nstep": "n-step DQN",
    "qrdqn": "QR-DQN",
    "qrdqn_nstep": "n-step QR-DQN",
    "offon_qrdqn": "OffOnQRDQN",
    "offon_dqn": "OffOnDQN (defaults)",
    "offon_mc_decay": "Off-On DQN (search's choice)",
    "offon_watkins": "Off-On λ",
    "offon_choice": "Off-On DQN (search's choice)",
    "offon_lambda": "Off-On λ",
    "offon_lambda_choice": "Off-On λ (search's choice)",
}
BASELINE = "dqn"
THRESHOLDS = {"CartPole-v1": 475.0, "MountainCar-v0": -110.0, "LunarLander-v3": 200.0, "Acrobot-v1": -100.0}
FALL_PENALTY, GOAL_BONUS = "CartPoleFallPenalty-v1", "MountainCarGoalBonus-v0"
SECTION_44 = (FALL_PENALTY, GOAL_BONUS)


# ----------------------------------------------------------------------------------------------------------------------
# Loading the finished runs
# ----------------------------------------------------------------------------------------------------------------------
@dataclass
class Run:
    algo: str
    env: str
    seed: int
    budget: int
    timesteps: np.ndarray  # evaluation steps
    returns: np.ndarray  # mean return of each evaluation
    episodes: pd.DataFrame  # training episodes, in order: r, l, t (+ goal_reached)
    # The hyperparameter set it trained with (its spec's "set"), which a grid's folder need not be named after: the
    # head-to-heads ran the "tuned" set into results/raw/headtohead*/ ("": not recorded)
    settings: str = ""
    # The steps at which it resumed from a checkpoint after an interruption (its done.json's "resumed_at")
    resumed_at: tuple[int, ...] = ()
    # The mean return of the episodes it played after training (final_evaluation.npz; None: it played none)
    final_score: float | None = None


def load_run(folder: Path) -> Run | None:
    """A finished run (as ``benchmark.py`` judges it), or None."""
    record = json.loads((folder / "done.json").read_text())
    try:
        with np.load(folder / "evaluations.npz") as data:
            timesteps, results = data["timesteps"], data["results"]
    except (OSError, ValueError, KeyError):
        return None
    monitors = sorted(folder.glob("*monitor.csv"))
    if record.get("returncode") != 0 or len(timesteps) != record.get("n_evaluations") or not monitors:
        return None
    # One file per training env; the first line is Monitor's JSON header. Episodes of all envs in time order.
    episodes = pd.concat([pd.read_csv(path, skiprows=1) for path in monitors]).sort_values("t", kind="stable")
    spec = record["spec"]
    final_score = None
    if (folder / "final_evaluation.npz").is_file():
        with np.load(folder / "final_evaluation.npz") as data:
            final_score = float(data["results"].mean())
    return Run(
        algo=spec["algo"],
        env=spec["env"],
        seed=spec["seed"],
        budget=spec["n_timesteps"],
        timesteps=timesteps.astype(np.int64),
        returns=results.mean(axis=1),
        episodes=episodes.reset_index(drop=True),
        settings=spec.get("set", ""),
        resumed_at=tuple(record.get("resumed_at", ())),
        final_score=final_score,
    )


def load_runs(folder: Path) -> dict[str, dict[str, list[Run]]]:
    """``runs[env][algo]``: the finished runs, by seed; envs and algos in a fixed order."""
    runs: dict[str, dict[str, list[Run]]] = {}
    for marker in sorted(folder.glob("*/*/done.json")):
        run = load_run(marker.parent)
        if run is None:
            print(f"Skipped (unfinished): {marker.parent}")
            continue
        runs.setdefault(run.env, {}).setdefault(run.algo, []).append(run)
    return {
        env: {algo: sorted(by_algo[algo], key=lambda run: run.seed) for algo in sorted(by_algo, key=algo_order)}
        for env, by_algo in sorted(runs.items())
    }


def algo_order(algo: str) -> tuple[int, str]:
    return (ALGOS.index(algo) if algo in ALGOS else len(ALGOS), algo)


def label(algo: str) -> str:
    return LABELS.get(algo, algo)


@contextmanager
def labels_of(labels: dict[str, str]) -> Iterator[None]:
    """Inside this block, :func:`label` names algorithms as ``labels`` says where it does (a study's own names)."""
    usual = dict(LABELS)
    LABELS.update(labels)
    try:
        yield
    finally:
        LABELS.clear()
        LABELS.update(usual)


def threshold(env: str) -> float | None:
    if env in THRESHOLDS:
        return THRESHOLDS[env]
    import gymnasium as gym

    import sb3_offon.envs  # noqa: F401  (registers the Section 4.4 envs)

    try:
        return gym.spec(env).reward_threshold
    except gym.error.Error:
        return None


# ----------------------------------------------------------------------------------------------------------------------
# Statistics: means over seeds with rliable's stratified bootstrap
# ----------------------------------------------------------------------------------------------------------------------
def interval_estimates(scores: dict, aggregate, reps: int) -> tuple[dict, dict]:
    """
    ``rly.get_interval_estimates``, reproducible and independent of the other entries of ``scores``.

    rliable's ``StratifiedBootstrap`` draws its resamples from NumPy's global RNG (``update_indices`` calls
    ``np.random.choice``) and ignores ``random_state``; given several algorithms at once it draws theirs one after the
    other, so an algorithm's interval would depend on which algorithms came before it. The global RNG is therefore
    seeded before each algorithm's estimate: the same scores give the same interval whoever asks, and with what. The
    columns (tasks) must come in a fixed order too: every caller passes them sorted by env id (``normalised_matrices``).
    """
    points, intervals = {}, {}
    for key, value in scores.items():
        np.random.seed(0)
        point, interval = rly.get_interval_estimates({key: value}, aggregate, reps=reps, random_state=np.random.RandomState(0))
        points[key], intervals[key] = point[key], interval[key]
    return points, intervals


def mean_ci(values: np.ndarray, reps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over runs (axis 0) of ``values`` shaped (runs,) or (runs, T), with its 95% bootstrap CI (low, high)."""
    scores = np.asarray(values, dtype=float).reshape(len(values), 1, -1)  # rliable's (runs, tasks, T)
    point, interval = interval_estimates({"x": scores}, lambda s: s.mean(axis=0)[0], reps)
    return point["x"], interval["x"][0], interval["x"][1]


def mean_interval(values: np.ndarray, reps: int) -> tuple[float, float]:
    """The 95% bootstrap CI (low, high) of the mean of one scalar per run, as ``mean_ci`` gives it."""
    _, low, high = mean_ci(values, reps)
    return float(low[0]), float(high[0])


def position(interval: tuple[float, float], baseline: tuple[float, float]) -> str:
    """Where an interval lies against the baseline's: "above, apart", "below, apart" or "overlapping"."""
    if interval[0] > baseline[1]:
        return "above, apart"
    return "below, apart" if interval[1] < baseline[0] else "overlapping"


def fast_probability_of_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """``metrics.probability_of_improvement`` (Mann-Whitney U / (n_x n_y), averaged over tasks), vectorised."""
    greater = (scores_x[:, None, :] > scores_y[None, :, :]).mean(axis=(0, 1))
    ties = (scores_x[:, None, :] == scores_y[None, :, :]).mean(axis=(0, 1))
    return float(np.mean(greater + 0.5 * ties))


def evaluation_curves(runs: list[Run]) -> tuple[np.ndarray, np.ndarray]:
    """The env's common grid of evaluation steps and every run's curve on it, (runs, T); held after a run's end."""
    grid = np.unique(np.concatenate([run.timesteps for run in runs]))
    return grid, np.stack([np.interp(grid, run.timesteps, run.returns) for run in runs])


def run_scores(
    runs: list[Run], grid: np.ndarray, curves: np.ndarray, last: int, solve_at: float | None, after_training: bool = False
) -> dict:
    """
    Per-run final return, AUC, steps to threshold (budget when never reached) and whether it was reached. The final
    return is the mean of the last ``last`` evaluations, or with ``after_training`` the run's ``final_score`` (the
    episodes it played after training; a run without them falls back to its last evaluations).
    """
    final = curves[:, -last:].mean(axis=1)
    if after_training:
        kept = zip(runs, final, strict=True)
        final = np.array([run.final_score if run.final_score is not None else mean for run, mean in kept])
    auc = np.trapezoid(curves, grid, axis=1) / (grid[-1] - grid[0]) if len(grid) > 1 else curves[:, 0]
    steps, solved = np.array([run.budget for run in runs], dtype=float), np.zeros(len(runs), dtype=bool)
    if solve_at is not None:
        for index, curve in enumerate(curves):
            reached = np.flatnonzero(curve >= solve_at)
            if len(reached):
                steps[index], solved[index] = grid[reached[0]], True
    return {"final": final, "auc": auc, "steps": steps, "solved": solved}


def two_sample_ci(x: np.ndarray, y: np.ndarray, statistic, reps: int) -> tuple[float, float, float]:
    """
    ``statistic(x, y, axis)`` and its 95% percentile bootstrap CI, the runs of ``x`` and ``y`` resampled apart (seeded);
    NaN bounds when a side has a single run (nothing to resample).
    """
    point = float(statistic(x, y, axis=-1))
    if min(len(x), len(y)) < 2:
        return point, np.nan, np.nan
    with warnings.catch_warnings():
        # Identical values on both sides (every run solved at the same step) give a zero-width interval: right as it is
        warnings.simplefilter("ignore", stats.DegenerateDataWarning)
        result = stats.bootstrap((x, y), statistic, n_resamples=reps, method="percentile", rng=0, paired=False)
    return point, float(result.confidence_interval.low), float(result.confidence_interval.high)


def mean_difference(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.mean(x, axis=axis) - np.mean(y, axis=axis)


def iqm_ratio(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """IQM of ``x`` over IQM of ``y``: rliable's IQM, the mean of the middle half (SciPy's 25% trimmed mean)."""
    return stats.trim_mean(x, 0.25, axis=axis) / stats.trim_mean(y, 0.25, axis=axis)


def fmt(values: np.ndarray, reps: int, digits: int = 1) -> str:
    point, low, high = (float(part[0]) for part in mean_ci(values, reps))
    return f"{point:,.{digits}f} [{low:,.{digits}f}, {high:,.{digits}f}]"


def interval_text(values: tuple[float, float, float], spec: str = ".2f") -> str:
    """``point [low, high]`` in the format ``spec``; ``point (one run)`` where there was nothing to resample (NaN bounds)."""
    point, low, high = values
    if np.isnan(low):
        return f"{point:{spec}} (one run)"
    return f"{point:{spec}} [{low:{spec}}, {high:{spec}}]"


# ----------------------------------------------------------------------------------------------------------------------
# Aggregates across envs (rliable)
# ----------------------------------------------------------------------------------------------------------------------
def incomplete_cells(by_algo: dict[str, list[Run]], algos: list[str]) -> str:
    """What one env still lacks against its most complete variant ("" when every variant has the same seeds)."""
    seeds = {algo: {run.seed for run in by_algo.get(algo, [])} for algo in algos}
    every = set.union(*seeds.values())
    missing = [
        f"{label(algo)} {len(seeds[algo])} of {len(every)} seeds" if seeds[algo] else f"no runs of {label(algo)}"
        for algo in algos
        if seeds[algo] != every
    ]
    return ", ".join(missing)


def aggregate_cells(runs: dict[str, dict[str, list[Run]]]) -> tuple[list[str], dict[str, str], list[str]]:
    """The envs an aggregate reads, those it leaves out (and why), and the algorithms, in the order of every table."""
    algos = sorted({algo for by_algo in runs.values() for algo in by_algo}, key=algo_order)
    envs = list(runs)
    if any(env not in SECTION_44 for env in envs):
        envs = [env for env in envs if env not in SECTION_44]
    # An env where a variant has no runs, or fewer seeds than another (runs still to come), waits until it is complete:
    # taken in, it would shrink that variant's aggregate to the seeds it has there, or leave the variant out
    left_out = {env: incomplete_cells(runs[env], algos) for env in envs}
    left_out = {env: cells for env, cells in left_out.items() if cells}
    return [env for env in envs if env not in left_out], left_out, algos


def normalised_matrices(runs: dict, scores: dict, envs: list[str], algos: list[str]) -> dict[str, dict[str, np.ndarray]]:
    """``matrices[measure][algo]``: (runs, tasks) of ``envs``' scores min-max normalised over every algorithm's runs there."""
    matrices: dict[str, dict[str, np.ndarray]] = {"final": {}, "auc": {}}
    envs = sorted(envs)  # the columns in one order for every caller: rliable's resamples follow it
    for measure in matrices:
        lows = {env: min(scores[env][algo][measure].min() for algo in algos) for env in envs}
        highs = {env: max(scores[env][algo][measure].max() for algo in algos) for env in envs}
        for algo in algos:
            # Per algo: the seeds it has on every env
            seeds = sorted(set.intersection(*({run.seed for run in runs[env][algo]} for env in envs)))
            columns = []
            for env in envs:
                by_seed = dict(zip((run.seed for run in runs[env][algo]), scores[env][algo][measure], strict=True))
                span = highs[env] - lows[env]
                columns.append([(by_seed[seed] - lows[env]) / span if span > 0 else 0.5 for seed in seeds])
            matrices[measure][algo] = np.array(columns).T
    return matrices


def aggregates(runs: dict[str, dict[str, list[Run]]], scores: dict, reps: int) -> dict | None:
    """IQM of min-max normalised final returns and AUC, and P(improvement over DQN), over the envs all variants ran."""
    envs, left_out, algos = aggregate_cells(runs)
    if not envs:
        return None
    matrices = normalised_matrices(runs, scores, envs, algos)
    result: dict = {
        "envs": envs,
        "left_out": left_out,
        "algos": algos,
        "runs": {algo: len(matrices["final"][algo]) for algo in algos},
    }
    for measure, matrix in matrices.items():
        point, interval = interval_estimates(matrix, lambda s: np.array([metrics.aggregate_iqm(s)]), reps)
        result[f"iqm_{measure}"] = {algo: (point[algo][0], *interval[algo][:, 0]) for algo in algos}
    if BASELINE in algos:
        pairs = {algo: (matrices["final"][algo], matrices["final"][BASELINE]) for algo in algos if algo != BASELINE}
        if pairs:
            # rliable's metric is Mann-Whitney U per task (one SciPy test per resample and task): the same figure is
            # computed vectorised inside rliable's bootstrap, and checked against rliable's own point estimate
            point, interval = interval_estimates(pairs, lambda x, y: np.array([fast_probability_of_improvement(x, y)]), reps)
            for algo, (x, y) in pairs.items():
                assert np.isclose(point[algo][0], metrics.probability_of_improvement(x, y))
            result["poi"] = {algo: (point[algo][0], *interval[algo][:, 0]) for algo in pairs}
    return result
