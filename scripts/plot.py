"""
Figures and tables of a benchmark written by ``scripts/benchmark.py``.

Reads every finished run (``done.json``) under ``<root>/<set>/<algo>/<env>_<seed>/`` (the zoo's layout) and writes
into ``--out`` (default ``results/<set>``):

- ``curves_<env>.png``, one per env: evaluation return (deterministic policy, ``evaluations.npz``) against env steps,
  mean over seeds with a 95% bootstrap confidence band, one line per variant (the paper's Figures 8, 10 and 12);
- ``fall_penalty_average.png``, ``fall_penalty_best.png``, ``fall_penalty_worst.png`` (with CartPoleFallPenalty-v1
  runs): the training score per episode (the episode length, i.e. the return without the -100, which is what the
  paper's scripts counted and what the stop rule averages) of the average, best and worst seed, Figures 13-15;
- ``goal_reaches.png`` (with MountainCarGoalBonus-v0 runs): the running count of training episodes that reached the
  goal against env steps, from the monitor CSV's ``goal_reached`` column, Figure 16;
- ``aggregate.png``: across envs, IQM of min-max normalised scores and probability of improvement over DQN;
- ``table.md``: per env and algorithm, final return, area under the curve and env steps to the solve threshold, each
  a mean over seeds with a 95% CI; the aggregates; the Section 4.4 measures.

With ``--page docs/benchmarks.md`` (the documentation's results page), the same tables also replace the block between
``<!-- results:<set>:start -->`` and ``<!-- results:<set>:end -->`` in that file (the text outside the markers is left
as it is; a file without the markers is an error), so that the page's tables are always the ones of ``table.md``.
``--readme`` is the option's former name, kept as an alias.

Definitions (per run; then mean over seeds with a 95% percentile stratified-bootstrap CI from rliable, seeded):

- evaluation curve: the mean return of each evaluation, put on the env's common grid of evaluation steps (a run that
  stopped early, e.g. by the CartPoleFallPenalty-v1 stop rule, keeps its last value: its policy no longer changes);
- final return: the mean of the last ``--last`` evaluations;
- AUC: the area under the evaluation curve divided by its span in env steps, i.e. the mean return over training;
- steps to threshold: the first evaluation step whose mean return reaches the threshold (CartPole 475, MountainCar
  -110, LunarLander 200, Acrobot -100; the registered ``reward_threshold`` for other envs); a run that never reaches
  it counts as its budget (a lower bound), and the table says how many reached it;
- aggregates (rliable): per env, final returns min-max normalised over all runs of all variants on that env; IQM over
  runs x envs; probability of improvement P(X > DQN) averaged over envs. The Section 4.4 envs are left out of the
  aggregates when other envs are present (their rewards were altered on purpose);
- against DQN, per env: the difference of mean final returns; whether the AUC's 95% CI lies above DQN's, below it, or
  overlaps it; the IQM over seeds of the steps to threshold divided by DQN's. These two intervals are percentile
  bootstraps that resample each algorithm's seeds apart (SciPy; the seeds are not paired).

Usage::

    python scripts/plot.py --root results/raw --set paper --out results/paper --page docs/benchmarks.md
"""

import argparse
import json
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from rliable import library as rly
from rliable import metrics
from scipy import stats

# arch (rliable's bootstrap) warns that ``random_state`` will change meaning; rliable passes it
warnings.filterwarnings("ignore", category=FutureWarning, module="arch")

ALGOS = ["offon_dqn", "dqn_mc", "dqn_sarsa", "dqn"]
LABELS = {
    "offon_dqn": "Off-On DQN",
    "dqn_mc": "DQN with MC",
    "dqn_sarsa": "DQN with Sarsa",
    "dqn": "DQN",
    "dqn_nstep": "n-step DQN",
    "qrdqn": "QR-DQN",
    "offon_choice": "Off-On DQN (search's choice)",
    "offon_lambda": "Off-On λ",
    "offon_lambda_choice": "Off-On λ (search's choice)",
}
COLORS = {
    "offon_dqn": "tab:red",
    "dqn_mc": "tab:green",
    "dqn_sarsa": "tab:orange",
    "dqn": "tab:blue",
    "dqn_nstep": "tab:purple",
    "qrdqn": "tab:brown",
    "offon_choice": "tab:pink",
    "offon_lambda": "tab:olive",
    "offon_lambda_choice": "tab:cyan",
}
BASELINE = "dqn"
THRESHOLDS = {"CartPole-v1": 475.0, "MountainCar-v0": -110.0, "LunarLander-v3": 200.0, "Acrobot-v1": -100.0}
PAPER_FIGURES = {"CartPole-v1": "Figure 8", "MountainCar-v0": "Figure 10", "LunarLander-v3": "Figure 12"}
FALL_PENALTY, GOAL_BONUS = "CartPoleFallPenalty-v1", "MountainCarGoalBonus-v0"
SECTION_44 = (FALL_PENALTY, GOAL_BONUS)
# The stop rule of Section 4.4 (and of the YAML entries): mean length of the last 100 training episodes >= 490
STOP_WINDOW, STOP_THRESHOLD = 100, 490.0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=Path("results/raw"), help="results root (default: results/raw)")
    parser.add_argument("--set", default="paper", help="hyperparameter set, a folder of the root (default: paper)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: results/<set>)")
    parser.add_argument("--last", type=int, default=3, help="evaluations averaged into the final return (default: 3)")
    parser.add_argument("--reps", type=int, default=2000, help="bootstrap resamples (default: 2000)")
    parser.add_argument(
        "--page",
        "--readme",
        dest="page",
        type=Path,
        default=None,
        help="also write the tables into this Markdown file (docs/benchmarks.md), between <!-- results:<set>:start --> and"
        " <!-- results:<set>:end --> (--readme: the former name)",
    )
    args = parser.parse_args(argv)
    args.out = args.out or Path("results") / args.set
    return args


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
    return Run(
        algo=spec["algo"],
        env=spec["env"],
        seed=spec["seed"],
        budget=spec["n_timesteps"],
        timesteps=timesteps.astype(np.int64),
        returns=results.mean(axis=1),
        episodes=episodes.reset_index(drop=True),
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


def scores_on_seeds(folder: Path, algos: tuple[str, ...], seeds: range, last: int = 3) -> tuple[dict, dict]:
    """
    ``runs[env][algo]`` and ``scores[env][algo]`` (``run_scores``'s fields) of the finished runs of ``algos`` on ``seeds``
    only: a head-to-head's rule reads its fresh seeds and nothing else.
    """
    runs: dict[str, dict[str, list[Run]]] = {}
    scores: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for env, by_algo in load_runs(folder).items():
        for algo in algos:
            kept = [run for run in by_algo.get(algo, []) if run.seed in seeds]
            if kept:
                grid, curves = evaluation_curves(kept)
                runs.setdefault(env, {})[algo] = kept
                scores.setdefault(env, {})[algo] = run_scores(kept, grid, curves, last, threshold(env))
    return runs, scores


def algo_order(algo: str) -> tuple[int, str]:
    return (ALGOS.index(algo) if algo in ALGOS else len(ALGOS), algo)


def label(algo: str) -> str:
    return LABELS.get(algo, algo)


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
    ``rly.get_interval_estimates``, reproducible: the same data give the same intervals at every redraw.

    rliable's ``StratifiedBootstrap`` draws its resamples from NumPy's global RNG (``update_indices`` calls
    ``np.random.choice``) and ignores ``random_state``, so the global RNG is seeded before each call.
    """
    np.random.seed(0)
    return rly.get_interval_estimates(scores, aggregate, reps=reps, random_state=np.random.RandomState(0))


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


def run_scores(runs: list[Run], grid: np.ndarray, curves: np.ndarray, last: int, solve_at: float | None) -> dict:
    """Per-run final return, AUC, steps to threshold (budget when never reached) and whether it was reached."""
    final = curves[:, -last:].mean(axis=1)
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


# ----------------------------------------------------------------------------------------------------------------------
# Figures
# ----------------------------------------------------------------------------------------------------------------------
def plot_band(ax: plt.Axes, x: np.ndarray, values: np.ndarray, algo: str, reps: int, text: str) -> None:
    mean, low, high = mean_ci(values, reps)
    ax.plot(x, mean, color=COLORS.get(algo), label=f"{label(algo)} ({text})")
    ax.fill_between(x, low, high, color=COLORS.get(algo), alpha=0.2, linewidth=0)


def save(fig: plt.Figure, path: Path, written: list[Path]) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    written.append(path)


def plot_curves(env: str, by_algo: dict[str, list[Run]], hyperparams_set: str, reps: int, out: Path, written: list) -> None:
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for algo, runs in by_algo.items():
        grid, curves = evaluation_curves(runs)
        plot_band(ax, grid, curves, algo, reps, f"{len(runs)} seed{'s' * (len(runs) > 1)}")
    if threshold(env) is not None:
        ax.axhline(threshold(env), color="grey", linestyle="--", linewidth=1, label=f"threshold {threshold(env):g}")
    figure = f", as the paper's {PAPER_FIGURES[env]}" if env in PAPER_FIGURES else ""
    ax.set(
        title=f"{env}: '{hyperparams_set}' settings{figure}",
        xlabel="Environment steps",
        ylabel="Evaluation return (deterministic)",
    )
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    save(fig, out / f"curves_{env}.png", written)


def episodes_to_stop(lengths: np.ndarray) -> int | None:
    """The number of episodes after which the stop rule holds (mean length of the last 100 >= 490), or None."""
    if len(lengths) < STOP_WINDOW:
        return None
    windows = np.convolve(lengths, np.ones(STOP_WINDOW) / STOP_WINDOW, mode="valid")
    hits = np.flatnonzero(windows >= STOP_THRESHOLD)
    return int(hits[0]) + STOP_WINDOW if len(hits) else None


def stop_point(run: Run) -> tuple[int, int, bool]:
    """Episodes and env steps until the stop rule held (all of the run's when it never did), and whether it did."""
    lengths = run.episodes["l"].to_numpy()
    stop = episodes_to_stop(lengths.astype(float))
    count = len(lengths) if stop is None else stop
    return count, int(lengths[:count].sum()), stop is not None


def rank_fall_penalty(runs: list[Run]) -> list[Run]:
    """Best first: stopped sooner (fewer episodes), then, among runs never stopped, the higher mean of the last 100."""

    def key(run: Run) -> tuple:
        lengths = run.episodes["l"].to_numpy(dtype=float)
        stop = episodes_to_stop(lengths)
        return (0, stop) if stop is not None else (1, -float(np.mean(lengths[-STOP_WINDOW:])))

    return sorted(runs, key=key)


def plot_fall_penalty(by_algo: dict[str, list[Run]], reps: int, out: Path, written: list) -> None:
    # Figure 13: mean over the seeds still training at each episode (runs end when the stop rule holds)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for algo, runs in by_algo.items():
        lengths = [run.episodes["l"].to_numpy(dtype=float) for run in runs]
        padded = np.full((len(runs), max(map(len, lengths))), np.nan)
        for index, values in enumerate(lengths):
            padded[index, : len(values)] = values
        mean, low, high = nan_mean_ci(padded, reps)
        episodes = np.arange(1, padded.shape[1] + 1)
        ax.plot(episodes, mean, color=COLORS.get(algo), label=f"{label(algo)} ({len(runs)} seeds)", linewidth=1)
        ax.fill_between(episodes, low, high, color=COLORS.get(algo), alpha=0.2, linewidth=0)
    decorate_fall_penalty(ax, "mean over the seeds still training (paper's Fig. 13)")
    save(fig, out / "fall_penalty_average.png", written)
    # Figures 14 and 15: each variant's best and worst seed
    for which, pick, figure in (("best", 0, "Fig. 14"), ("worst", -1, "Fig. 15")):
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for algo, runs in by_algo.items():
            run = rank_fall_penalty(runs)[pick]
            lengths = run.episodes["l"].to_numpy(dtype=float)
            stop = episodes_to_stop(lengths)
            status = f"stopped after {stop} episodes" if stop is not None else f"not stopped in {len(lengths)} episodes"
            ax.plot(
                np.arange(1, len(lengths) + 1),
                lengths,
                color=COLORS.get(algo),
                linewidth=1,
                label=f"{label(algo)}: seed {run.seed}, {status}",
            )
        decorate_fall_penalty(ax, f"{which} seed of each variant (paper's {figure})")
        save(fig, out / f"fall_penalty_{which}.png", written)


def nan_mean_ci(values: np.ndarray, reps: int, chunk: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Mean over runs (axis 0) ignoring NaN (runs that ended), with a 95% percentile bootstrap CI over runs.

    rliable's bootstrap needs complete arrays; runs of different lengths are resampled here the same way (runs drawn
    with replacement), each resample's mean taken over the runs still present.
    """
    generator = np.random.default_rng(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns of a resample
        samples = []
        for start in range(0, reps, chunk):
            draws = generator.integers(0, len(values), size=(min(chunk, reps - start), len(values)))
            samples.append(np.nanmean(values[draws], axis=1))
        low, high = np.nanpercentile(np.concatenate(samples), [2.5, 97.5], axis=0)
        return np.nanmean(values, axis=0), low, high


def decorate_fall_penalty(ax: plt.Axes, subtitle: str) -> None:
    ax.axhline(STOP_THRESHOLD, color="grey", linestyle="--", linewidth=1, label=f"stop rule: mean of {STOP_WINDOW} ≥ 490")
    ax.set_title(f"{FALL_PENALTY}: {subtitle}", fontsize=10)
    ax.set(
        xlabel="Training episode",
        ylabel="Score (episode length, steps balanced)",
    )
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)


def goal_episodes(run: Run) -> np.ndarray:
    """The env step at which each training episode that reached the goal ended (the monitor CSV's ``goal_reached``)."""
    if "goal_reached" not in run.episodes:
        raise SystemExit(f"{GOAL_BONUS} run without a goal_reached column in its monitor CSV: {run.algo} seed {run.seed}")
    ends = run.episodes["l"].cumsum().to_numpy()
    reached = run.episodes["goal_reached"].astype(str).str.strip().str.lower().isin(["true", "1", "1.0"]).to_numpy()
    return ends[reached]


def goal_counts(runs: list[Run], grid: np.ndarray) -> np.ndarray:
    """(runs, T): the number of training episodes that reached the goal and ended by each step of ``grid``."""
    return np.array([np.searchsorted(goal_episodes(run), grid, side="right") for run in runs], dtype=float)


def plot_goal_reaches(by_algo: dict[str, list[Run]], reps: int, out: Path, written: list) -> None:
    fig, ax = plt.subplots(figsize=(7, 4.5))
    budget = max(run.budget for runs in by_algo.values() for run in runs)
    grid = np.linspace(0, budget, 201)
    for algo, runs in by_algo.items():
        plot_band(ax, grid, goal_counts(runs, grid), algo, reps, f"{len(runs)} seed{'s' * (len(runs) > 1)}")
    ax.set(
        title=f"{GOAL_BONUS}: goal reaches in training (paper's Figure 16)",
        xlabel="Environment steps",
        ylabel="Training episodes that reached the goal",
    )
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    save(fig, out / "goal_reaches.png", written)


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


def aggregates(runs: dict[str, dict[str, list[Run]]], scores: dict, reps: int) -> dict | None:
    """IQM of min-max normalised final returns and AUC, and P(improvement over DQN), over the envs all variants ran."""
    algos = sorted({algo for by_algo in runs.values() for algo in by_algo}, key=algo_order)
    envs = list(runs)
    if any(env not in SECTION_44 for env in envs):
        envs = [env for env in envs if env not in SECTION_44]
    # An env where a variant has no runs, or fewer seeds than another (runs still to come), waits until it is complete:
    # taken in, it would shrink that variant's aggregate to the seeds it has there, or leave the variant out
    left_out = {env: incomplete_cells(runs[env], algos) for env in envs}
    left_out = {env: cells for env, cells in left_out.items() if cells}
    envs = [env for env in envs if env not in left_out]
    if not envs:
        return None
    # Per algo: (runs, tasks) on the seeds it has on every env
    matrices: dict[str, dict[str, np.ndarray]] = {"final": {}, "auc": {}}
    for measure in matrices:
        lows = {env: min(scores[env][algo][measure].min() for algo in algos) for env in envs}
        highs = {env: max(scores[env][algo][measure].max() for algo in algos) for env in envs}
        for algo in algos:
            seeds = sorted(set.intersection(*({run.seed for run in runs[env][algo]} for env in envs)))
            columns = []
            for env in envs:
                by_seed = dict(zip((run.seed for run in runs[env][algo]), scores[env][algo][measure], strict=True))
                span = highs[env] - lows[env]
                columns.append([(by_seed[seed] - lows[env]) / span if span > 0 else 0.5 for seed in seeds])
            matrices[measure][algo] = np.array(columns).T
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


def plot_aggregates(result: dict, out: Path, written: list) -> None:
    panels = [("iqm_final", "IQM of normalised final return"), ("iqm_auc", "IQM of normalised AUC")]
    if "poi" in result:
        panels.append(("poi", f"P(improvement over {label(BASELINE)})"))
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 0.6 * len(result["algos"]) + 1.6), squeeze=False)
    for ax, (key, title) in zip(axes[0], panels, strict=True):
        algos = list(result[key])
        for row, algo in enumerate(algos):
            point, low, high = result[key][algo]
            ax.barh(row, high - low, left=low, color=COLORS.get(algo), alpha=0.6, height=0.6)
            ax.plot([point, point], [row - 0.3, row + 0.3], color="black", linewidth=2)
        ax.set_yticks(range(len(algos)), [label(algo) for algo in algos])
        ax.set_title(title, fontsize=10)
        ax.set_xlim(0, 1)
        if key == "poi":
            ax.axvline(0.5, color="grey", linestyle="--", linewidth=1)
        ax.grid(axis="x", alpha=0.3)
    fig.suptitle(f"Across {', '.join(result['envs'])} (95% bootstrap CIs)", fontsize=10)
    save(fig, out / "aggregate.png", written)


# ----------------------------------------------------------------------------------------------------------------------
# Table
# ----------------------------------------------------------------------------------------------------------------------
def left_out_text(left_out: dict[str, str]) -> str:
    if not left_out:
        return ""
    return (
        " (left out until every variant has the same seeds there: "
        + "; ".join(f"{env}, {cells}" for env, cells in left_out.items())
        + ")"
    )


def interval_text(values: tuple[float, float, float], spec: str = ".2f") -> str:
    """``point [low, high]`` in the format ``spec``; ``point (one run)`` where there was nothing to resample (NaN bounds)."""
    point, low, high = values
    if np.isnan(low):
        return f"{point:{spec}} (one run)"
    return f"{point:{spec}} [{low:{spec}}, {high:{spec}}]"


def command_text(args: argparse.Namespace) -> str:
    page = f" --page {args.page}" if args.page is not None else ""
    return f"python scripts/plot.py --root {args.root} --set {args.set} --out {args.out}{page}"


def table_sections(args: argparse.Namespace, runs: dict, scores: dict, result: dict | None) -> list[tuple[str, list[str]]]:
    """The tables, as (title, lines): ``table.md``'s sections, and the page's block."""
    lines = [
        "| Env | Algorithm | Seeds | Budget | Final return | AUC | Steps to threshold | Solved |",
        "|---|---|---:|---:|---|---|---|---:|",
    ]
    for env, by_algo in runs.items():
        solve_at = threshold(env)
        env_text = f"{env} (≥ {solve_at:g})" if solve_at is not None else env
        for algo, algo_runs in by_algo.items():
            score = scores[env][algo]
            budget = max(run.budget for run in algo_runs)
            steps = fmt(score["steps"], args.reps, 0) if solve_at is not None else "—"
            solved = f"{int(score['solved'].sum())}/{len(algo_runs)}" if solve_at is not None else "—"
            lines.append(
                f"| {env_text} | {label(algo)} | {len(algo_runs)} | {budget:,} | {fmt(score['final'], args.reps)} "
                f"| {fmt(score['auc'], args.reps)} | {steps} | {solved} |"
            )
    sections = [("Per environment and algorithm", lines)]
    if result is not None:
        lines = [
            f"Envs: {', '.join(result['envs'])}{left_out_text(result['left_out'])}. Per env, scores min-max normalised "
            "over all runs of all variants; IQM over runs x envs (seeds present on every env); probability of improvement "
            "P(X > DQN) per env, averaged over envs.",
            "",
            f"| Algorithm | Runs | IQM normalised final return | IQM normalised AUC | P(improvement over {label(BASELINE)}) |",
            "|---|---:|---|---|---|",
        ]
        for algo in result["algos"]:
            poi = interval_text(result["poi"][algo]) if algo in result.get("poi", {}) else "—"
            lines.append(
                f"| {label(algo)} | {result['runs'][algo]} | {interval_text(result['iqm_final'][algo])} "
                f"| {interval_text(result['iqm_auc'][algo])} | {poi} |"
            )
        sections.append(("Across environments (rliable)", lines))
    lines = against_baseline(args, runs, scores)
    if lines:
        sections.append((f"Against {label(BASELINE)}", lines))
    if FALL_PENALTY in runs:
        lines = [
            f"Training stops once the mean length of the last {STOP_WINDOW} training episodes reaches {STOP_THRESHOLD:g}. "
            "A run that never stops counts with all its episodes and steps (lower bounds).",
            "",
            "| Algorithm | Seeds | Episodes to stop | Env steps to stop | Stopped |",
            "|---|---:|---|---|---:|",
        ]
        for algo, algo_runs in runs[FALL_PENALTY].items():
            episodes, steps, stopped = np.array([stop_point(run) for run in algo_runs], dtype=float).T
            lines.append(
                f"| {label(algo)} | {len(algo_runs)} | {fmt(episodes, args.reps, 0)} | {fmt(steps, args.reps, 0)} "
                f"| {int(stopped.sum())}/{len(algo_runs)} |"
            )
        sections.append((f"Section 4.4: {FALL_PENALTY}", lines))
    if GOAL_BONUS in runs:
        lines = [
            "Training episodes that reached the goal (the monitor CSV's `goal_reached`), over the whole run.",
            "",
            "| Algorithm | Seeds | Goal reaches | Training episodes | First goal (env step) |",
            "|---|---:|---|---|---|",
        ]
        for algo, algo_runs in runs[GOAL_BONUS].items():
            totals = goal_counts(algo_runs, np.array([np.inf]))[:, 0]
            episodes = np.array([len(run.episodes) for run in algo_runs], dtype=float)
            firsts = np.array([(goal_episodes(run)[:1].tolist() or [np.nan])[0] for run in algo_runs], dtype=float)
            first_text = fmt(firsts, args.reps, 0) if not np.isnan(firsts).any() else "not reached by every seed"
            lines.append(
                f"| {label(algo)} | {len(algo_runs)} | {fmt(totals, args.reps)} | {fmt(episodes, args.reps)} | {first_text} |"
            )
        sections.append((f"Section 4.4: {GOAL_BONUS}", lines))
    return sections


def against_baseline(args: argparse.Namespace, runs: dict, scores: dict) -> list[str]:
    """Per env, every other algorithm against DQN: the measures of issue 13's targets (no lines without DQN)."""
    header = [
        f"Per env: mean final return minus {label(BASELINE)}'s; where the AUC's 95% CI lies against {label(BASELINE)}'s "
        f"(apart above, apart below, or overlapping); the IQM over seeds of the steps to threshold divided by "
        f"{label(BASELINE)}'s (runs that never reach it count as their budget). Bracketed: 95% percentile bootstrap CIs, "
        "seeds resampled apart.",
        "",
        f"| Env | Algorithm | Final return minus {label(BASELINE)}'s | AUC against {label(BASELINE)}'s | "
        f"IQM steps to threshold ÷ {label(BASELINE)}'s |",
        "|---|---|---|---|---|",
    ]
    rows = []
    for env, by_algo in runs.items():
        if BASELINE not in by_algo or env in SECTION_44:
            continue
        baseline = scores[env][BASELINE]
        baseline_auc = mean_interval(baseline["auc"], args.reps)
        for algo in by_algo:
            if algo == BASELINE:
                continue
            score = scores[env][algo]
            difference = two_sample_ci(score["final"], baseline["final"], mean_difference, args.reps)
            auc = position(mean_interval(score["auc"], args.reps), baseline_auc)
            if min(len(score["auc"]), len(baseline["auc"])) < 2:
                auc = "(one run)"  # a single run's CI is a point: "apart" would claim what one seed cannot show
            ratio = "—"
            if threshold(env) is not None:
                ratio = interval_text(two_sample_ci(score["steps"], baseline["steps"], iqm_ratio, args.reps))
            rows.append(f"| {env} | {label(algo)} | {interval_text(difference, '+,.1f')} | {auc} | {ratio} |")
    return header + rows if rows else []


def write_table(args: argparse.Namespace, n_runs: int, sections: list[tuple[str, list[str]]], written: list) -> None:
    lines = [
        f"# Benchmark results: `{args.set}` hyperparameters",
        "",
        f"From {n_runs} finished runs under `{args.root / args.set}` (`{command_text(args)}`). Means over seeds with 95% "
        f"stratified-bootstrap confidence intervals (rliable, {args.reps} resamples). Returns are of the deterministic "
        "policy, evaluated periodically during training.",
        "",
        f"- **Final return**: mean of the last {args.last} evaluations.",
        "- **AUC**: area under the evaluation curve divided by its span in env steps (the mean return over training).",
        "- **Steps to threshold**: first evaluation step whose mean return reaches the threshold; a run that never "
        "reaches it counts as its budget (so the mean is a lower bound), and *solved* says how many reached it.",
    ]
    for title, body in sections:
        lines += ["", f"## {title}", "", *body]
    path = args.out / "table.md"
    path.write_text("\n".join(lines) + "\n")
    written.append(path)


def page_markers(hyperparams_set: str) -> tuple[str, str]:
    return f"<!-- results:{hyperparams_set}:start -->", f"<!-- results:{hyperparams_set}:end -->"


def page_block(args: argparse.Namespace, n_runs: int, sections: list[tuple[str, list[str]]], page: Path) -> str:
    """The page's copy of the tables: ``table.md``'s sections under bold titles, not headings of the page's own."""
    table = Path(os.path.relpath(args.out.resolve() / "table.md", page.resolve().parent)).as_posix()
    name = (args.out / "table.md").as_posix()  # as the command named it: results/<set>/table.md
    lines = [
        f"<!-- Written by `{command_text(args)}`: edit scripts/plot.py, not this block. -->",
        f"From {n_runs} runs: means over seeds with 95% stratified-bootstrap CIs; definitions in [{name}]({table}).",
    ]
    for title, body in sections:
        lines += ["", f"**{title}**", "", *body]
    return "\n".join(lines)


def check_page(path: Path, hyperparams_set: str) -> str:
    """The text of ``path``, which must hold the set's start and end markers once each, in that order."""
    start, end = page_markers(hyperparams_set)
    if not path.is_file():
        raise SystemExit(f"--page {path}: no such file")
    text = path.read_text()
    for marker in (start, end):
        if text.count(marker) != 1:
            found = "not found" if marker not in text else f"found {text.count(marker)} times"
            raise SystemExit(f"{path}: the marker {marker} is {found}; put {start} and {end}, once each, where the tables go")
    if text.index(end) < text.index(start):
        raise SystemExit(f"{path}: the marker {end} comes before {start}")
    return text


def replace_page_block(path: Path, hyperparams_set: str, block: str) -> None:
    """Put ``block`` between the set's two markers of ``path``; the text outside them is kept as it is."""
    start, end = page_markers(hyperparams_set)
    head, rest = check_page(path, hyperparams_set).split(start)
    tail = rest.split(end)[1]
    # A blank line before the end marker: a table ends there in every Markdown reader
    path.write_text(f"{head}{start}\n{block}\n\n{end}{tail}")


# ----------------------------------------------------------------------------------------------------------------------
# Main
# ----------------------------------------------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.page is not None:
        check_page(args.page, args.set)  # before the work, not after it
    runs = load_runs(args.root / args.set)
    if not runs:
        raise SystemExit(f"No finished run under {args.root / args.set}")
    args.out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    scores: dict[str, dict[str, dict]] = {}
    for env, by_algo in runs.items():
        plot_curves(env, by_algo, args.set, args.reps, args.out, written)
        scores[env] = {}
        for algo, algo_runs in by_algo.items():
            grid, curves = evaluation_curves(algo_runs)
            scores[env][algo] = run_scores(algo_runs, grid, curves, args.last, threshold(env))
    if FALL_PENALTY in runs:
        plot_fall_penalty(runs[FALL_PENALTY], args.reps, args.out, written)
    if GOAL_BONUS in runs:
        plot_goal_reaches(runs[GOAL_BONUS], args.reps, args.out, written)
    result = aggregates(runs, scores, args.reps)
    if result is not None:
        plot_aggregates(result, args.out, written)
    sections = table_sections(args, runs, scores, result)
    n_runs = sum(len(by_seed) for by_algo in runs.values() for by_seed in by_algo.values())
    write_table(args, n_runs, sections, written)
    if args.page is not None:
        replace_page_block(args.page, args.set, page_block(args, n_runs, sections, args.page))
        written.append(args.page)
    print("Wrote:\n  " + "\n  ".join(str(path) for path in written))


if __name__ == "__main__":
    main()
