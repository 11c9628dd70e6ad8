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

The studies of ``benchmarks/`` are reported by ``scripts/study.py``, which calls :func:`report` on each study's runs
(named as the study file names them); this command reports any grid folder as it is.

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

    python scripts/plot.py --root results/raw --set my_grid --out results/my_grid
"""

import argparse
import sys
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_stats import (
    BASELINE,
    FALL_PENALTY,
    GOAL_BONUS,
    SECTION_44,
    Run,
    aggregates,
    evaluation_curves,
    fmt,
    interval_text,
    iqm_ratio,
    label,
    load_runs,
    mean_ci,
    mean_difference,
    mean_interval,
    position,
    run_scores,
    threshold,
    two_sample_ci,
)

COLORS = {
    "offon_paper": "tab:red",
    "offon_dqn": "tab:cyan",
    "dqn_mc": "tab:green",
    "dqn_sarsa": "tab:orange",
    "dqn": "tab:blue",
    "dqn_nstep": "tab:purple",
    "qrdqn": "tab:brown",
    "qrdqn_nstep": "tab:gray",
    "offon_qrdqn": "tab:olive",
    "offon_choice": "tab:pink",
    "offon_lambda": "tab:olive",
    "offon_lambda_choice": "tab:cyan",
}
PAPER_FIGURES = {"CartPole-v1": "Figure 8", "MountainCar-v0": "Figure 10", "LunarLander-v3": "Figure 12"}
# The stop rule of Section 4.4 (and of the YAML entries): mean length of the last 100 training episodes >= 490
STOP_WINDOW, STOP_THRESHOLD = 100, 490.0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=Path("results/raw"), help="results root (default: results/raw)")
    parser.add_argument("--set", default="paper", help="hyperparameter set, a folder of the root (default: paper)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: results/<set>)")
    parser.add_argument("--last", type=int, default=3, help="evaluations averaged into the final return (default: 3)")
    parser.add_argument("--reps", type=int, default=2000, help="bootstrap resamples (default: 2000)")
    args = parser.parse_args(argv)
    args.out = args.out or Path("results") / args.set
    return args


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
    ax.set(
        title=curves_title(env, by_algo, hyperparams_set),
        xlabel="Environment steps",
        ylabel="Evaluation return (deterministic)",
    )
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    save(fig, out / f"curves_{env}.png", written)


def curves_title(env: str, by_algo: dict[str, list[Run]], grid: str) -> str:
    """The env, the hyperparameter set(s) its runs trained with, and the grid's name where it is not that set."""
    settings = sorted({run.settings or grid for runs in by_algo.values() for run in runs})
    named = "', '".join(settings)
    figure = f", as the paper's {PAPER_FIGURES[env]}" if env in PAPER_FIGURES else ""
    title = f"{env}: '{named}' settings{figure}"
    return title if settings == [grid] else f"{title}\ngrid '{grid}'"  # on a line of its own: the figure is narrow


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
# Aggregates across envs (computed in run_stats.py)
# ----------------------------------------------------------------------------------------------------------------------
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


def command_text(args: argparse.Namespace) -> str:
    """The command that wrote the report: a study's (``args.command``), or this script's."""
    return getattr(args, "command", None) or f"python scripts/plot.py --root {args.root} --set {args.set} --out {args.out}"


def table_sections(args: argparse.Namespace, runs: dict, scores: dict, result: dict | None) -> list[tuple[str, list[str]]]:
    """The tables, as (title, lines): ``table.md``'s sections."""
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
    """Per env, every other algorithm against DQN: the measures of the first head-to-head's targets (no lines without DQN)."""
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


# ----------------------------------------------------------------------------------------------------------------------
# Main
# ----------------------------------------------------------------------------------------------------------------------
def report(args: argparse.Namespace, runs: dict[str, dict[str, list[Run]]]) -> list[Path]:
    """
    Write the figures and ``table.md`` of ``runs`` (``runs[env][algo]``, as ``load_runs`` gives them) into ``args.out``.

    :param args: ``root``, ``set`` (the runs' folder under it), ``out``, ``last``, ``reps``; optionally ``command``, the
        command named in ``table.md`` (default: this script's)
    :param runs: the finished runs to report
    :return: the files written
    """
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
    return written


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    runs = load_runs(args.root / args.set)
    if not runs:
        raise SystemExit(f"No finished run under {args.root / args.set}")
    written = report(args, runs)
    print("Wrote:\n  " + "\n  ".join(str(path) for path in written))


if __name__ == "__main__":
    main()
