"""
Judge and report a study stated as a file (``benchmarks/<study>.yml``): its tables, figures and verdict, from its runs.

What a study file holds: ``scripts/study_file.py``; its rule's criteria and verdict: ``scripts/rule.py``.
``also_against`` lists the other algorithms the same criteria are reported for. The report (``tables``): ``study``
(the default) writes this script's tables and figures with the verdict in ``table.md``; ``benchmark`` writes
``scripts/plot.py``'s (per-env tables with steps to threshold, the paper's figures, aggregates) and the verdict, if the
study has a rule, in ``verdict.md``. A ``setup_check`` block (``algo``, ``seeds``, ``name``) is judged with
``--setup-check``: the algorithm's final evaluation episodes against a random policy's return (``--random``, from
``scripts/random_policy.py``). ``--seeds`` and ``--envs`` judge and report the study on some of its seeds or envs
only, into a folder of their own: an interim look while runs are missing (the seeds, or the envs, on which every
algorithm has finished), marked as such in its table; the study's verdict is the one on all its seeds and envs.
``--by-seed`` prints the candidate's runs beside its references' on the same seeds and writes nothing.

Usage::

    python scripts/study.py benchmarks/minatar.yml                # tables, figures and verdict into results/minatar/
    python scripts/study.py benchmarks/minatar.yml --setup-check --random results/minatar/random_policy.json
    python scripts/study.py benchmarks/minatar.yml --seeds 40 41 42 43   # into results/minatar/seeds_40_41_42_43/
    python scripts/study.py benchmarks/classic_qr.yml --envs CartPole-v1 Acrobot-v1   # results/classic_qr/envs_.../
    python scripts/study.py benchmarks/minatar_horizon_judgement.yml --by-seed   # the runs so far, paired by seed
"""

import argparse
import json
import sys
import textwrap
from dataclasses import dataclass, replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
# The other scripts sit next to this one: importable however it is started
sys.path.insert(0, str(Path(__file__).resolve().parent))
import matplotlib.pyplot as plt
import numpy as np
import plot
import selection
from rule import (
    final_difference,
    interval,
    iqm_intervals,
    judge_criterion,
    study_runs,
    verdict,
)
from run_records import env_folder
from run_stats import evaluation_curves, labels_of, mean_ci
from scipy import stats
from study_file import MINMAX, Study

COLORS = {
    "dqn": "tab:blue",
    "dqn_nstep": "tab:orange",
    "qrdqn": "tab:green",
    "offon_lambda_choice": "tab:red",
    "qrdqn_nstep": "tab:purple",
    "offon_qrdqn": "tab:brown",
}
PALETTE = [f"tab:{name}" for name in ("blue", "orange", "green", "red", "purple", "brown", "pink", "gray", "olive", "cyan")]


def algo_colors(algos: list[str]) -> dict[str, str]:
    """A colour per algorithm of a study, no two alike: the fixed colour where it has one (so that figures of different
    studies agree), the next unused colour of the palette for the rest (a study's candidates, named by the study)."""
    colors = {algo: COLORS[algo] for algo in algos if algo in COLORS}
    free = iter(color for color in PALETTE if color not in colors.values())
    return {algo: colors.get(algo) or next(free, "black") for algo in algos}


# ----------------------------------------------------------------------------------------------------------------------
# Report: tables and figures
# ----------------------------------------------------------------------------------------------------------------------
def per_env_table(study: Study, runs: dict, scores: dict, measure: str) -> list[str]:
    header = " | ".join(study.label(algo) for algo in study.algos)
    lines = [f"| env | {header} |", "|---|" + "---:|" * len(study.algos)]
    for env in study.envs:
        cells = []
        for algo in study.algos:
            values = scores.get(env, {}).get(algo, {}).get(measure)
            if values is None:
                cells.append("-")
                continue
            point, low, high = (float(part[0]) for part in mean_ci(values, study.reps_iqm))
            text = interval((point, low, high)) if len(values) > 1 else f"{point:.2f}"  # the count follows
            cells.append(f"{text} ({len(values)})")
        lines.append(f"| {env} | {' | '.join(cells)} |")
    return lines


def published_table(study: Study) -> list[str]:
    """The published scores of ``study.published`` per env, one column per agent ("-" where none is given)."""
    agents = list(study.published)
    lines = [f"| env | {' | '.join(agents)} |", "|---|" + "---:|" * len(agents)]
    for env in study.envs:
        cells = [f"{study.published[agent][env]:g}" if env in study.published[agent] else "-" for agent in agents]
        lines.append(f"| {env} | {' | '.join(cells)} |")
    return lines


def by_seed_table(study: Study, runs: dict, scores: dict) -> list[str]:
    """
    Each run of the candidate (a study without one: of its first algorithm), final / AUC, beside the runs of the rule's
    references and of ``also_against`` on the same env and seed ("-" where that run is not in): a look at a study's
    runs while they come in, paired by seed, which places nothing (one seed carries no interval).
    """
    first = study.candidate or study.algos[0]
    others = [*(criterion["reference"] for criterion in study.rule), *study.also_against]
    algos = list(dict.fromkeys([first, *(algo for algo in others if algo in study.algos)]))
    lines = [
        "| env | seed | " + " | ".join(study.label(algo) for algo in algos) + " |",
        "|---|---:|" + "---:|" * len(algos),
    ]
    for env in study.envs:
        by_algo = {algo: {run.seed: index for index, run in enumerate(runs.get(env, {}).get(algo, []))} for algo in algos}
        for seed in sorted(by_algo[first]):
            cells = []
            for algo in algos:
                index = by_algo[algo].get(seed)
                if index is None:
                    cells.append("-")
                    continue
                scored = scores[env][algo]
                cells.append(f"{scored['final'][index]:.2f} / {scored['auc'][index]:.2f}")
            lines.append(f"| {env} | {seed} | {' | '.join(cells)} |")
    return lines


def difference_references(study: Study) -> list[str]:
    """
    The algorithms the report subtracts every other's final return from: DQN, then each reference of a
    ``final_not_below`` or ``auc_not_below`` criterion of the rule (QR-DQN's, say), so that every algorithm of the study
    is also read against the one the rule holds the candidate to, not the candidate alone.
    """
    references = ["dqn"] + [
        criterion["reference"] for criterion in study.rule if criterion["kind"] in ("final_not_below", "auc_not_below")
    ]
    return [algo for algo in dict.fromkeys(references) if algo in study.algos]


def difference_table(study: Study, scores: dict, reference: str = "dqn") -> list[str]:
    others = [algo for algo in study.algos if algo != reference]
    name = study.label(reference)
    lines = [f"| env | {' | '.join(f'{study.label(algo)} - {name}' for algo in others)} |", "|---|" + "---:|" * len(others)]
    for env in study.envs:
        cells = []
        for algo in others:
            difference = final_difference(study, scores, env, algo, reference)
            cells.append("-" if difference is None else interval(difference, "+.2f"))
        lines.append(f"| {env} | {' | '.join(cells)} |")
    return lines


@dataclass(frozen=True)
class Interim:
    """What an interim look narrows a study to: some of its seeds, some of its envs, or both (None: all of them)."""

    seeds: list[int] | None = None
    envs: list[str] | None = None

    def arguments(self) -> str:
        """The command-line arguments that ask for this look."""
        seeds = f" --seeds {' '.join(map(str, self.seeds))}" if self.seeds else ""
        return seeds + (f" --envs {' '.join(self.envs)}" if self.envs else "")

    def words(self) -> str:
        """This look in words: ``seeds 1, 2``, ``CartPole-v1, Acrobot-v1`` or ``seeds 1, 2 on CartPole-v1``."""
        seeds = f"seeds {', '.join(map(str, self.seeds))}" if self.seeds else ""
        envs = ", ".join(self.envs) if self.envs else ""
        return f"{seeds} on {envs}" if seeds and envs else seeds or envs

    def note(self, study_command: str) -> str:
        """The sentence that marks a report as this look, with what its figures lack; ``study_command``: the study's own."""
        narrowed = " and ".join(name for name, values in (("seeds", self.seeds), ("envs", self.envs)) if values)
        caveats = []
        if self.seeds:
            caveats.append("Bootstrap intervals over a few seeds are too narrow: they resample only the seeds there are.")
        if self.envs:
            caveats.append("Aggregates over some of the envs are not the study's.")
        return (
            f"An interim look at {self.words()} only, not the study's verdict, which is on all its {narrowed} "
            f"(`{study_command}`). {' '.join(caveats)}"
        )

    def folder(self) -> str:
        """Its report's folder name: ``seeds_1_2``, ``envs_CartPole-v1_Acrobot-v1``, or both joined by ``_``."""
        parts = [f"seeds_{'_'.join(map(str, self.seeds))}"] if self.seeds else []
        return "_".join([*parts, *([f"envs_{'_'.join(map(env_folder, self.envs))}"] if self.envs else [])])


def command(study: Study, interim: Interim | None = None) -> str:
    """The command line that writes the report: the study file, and what an interim look narrows it to."""
    return f"python scripts/study.py {study.path.as_posix()}{interim.arguments() if interim else ''}"


def refuse_candidates_with_own(study: Study, key: str) -> None:
    """``--seeds`` and ``--envs`` narrow the study's own seeds or envs: a search whose candidates have ``key`` of their
    own is refused, naming them."""
    own = sorted(name for name, candidate in study.candidates.items() if key in candidate)
    if own:
        raise ValueError(
            f"{study.path}: --{key} applies to a study whose candidates have no {key} of their own ({', '.join(own)})"
        )


def env_subset(study: Study, envs: list[str]) -> Study:
    """``study`` on ``envs`` only (each one of its envs, kept in the study's order; a fixed normalisation narrowed too)."""
    refuse_candidates_with_own(study, "envs")
    unknown = sorted(set(envs) - set(study.envs))
    if unknown:
        raise ValueError(f"--envs: {', '.join(unknown)} not among the study's envs {study.envs}")
    normalisation = study.normalisation
    if isinstance(normalisation, dict):
        normalisation = {env: low_high for env, low_high in normalisation.items() if env in envs}
    return replace(study, envs=[env for env in study.envs if env in envs], normalisation=normalisation)


def seed_subset(study: Study, seeds: list[int]) -> Study:
    """
    ``study`` on ``seeds`` only (each one of its seeds): every env's seeds narrowed to them, so that the rule reads a run
    of every algorithm on every env for each of them. A search whose candidates have seeds of their own is not narrowed;
    a head-to-head whose candidates take the study's seeds is.
    """
    refuse_candidates_with_own(study, "seeds")
    unknown = sorted(set(seeds) - set(study.seeds) - {seed for env_seeds in study.seeds_on.values() for seed in env_seeds})
    if unknown:
        raise ValueError(f"--seeds: {', '.join(map(str, unknown))} not among the study's seeds {study.seeds}")
    keep = sorted(set(seeds))
    narrowed = replace(
        study,
        seeds=[seed for seed in study.seeds if seed in keep],
        seeds_on={env: [seed for seed in env_seeds if seed in keep] for env, env_seeds in study.seeds_on.items()},
    )
    empty = [env for env in sorted(study.envs) if not narrowed.seeds_on.get(env, narrowed.seeds)]
    if empty:
        raise ValueError(f"--seeds: none of {keep} is a seed of {', '.join(empty)} in {study.path}")
    return narrowed


def rule_lines(
    study: Study, runs: dict, scores: dict, decision: str, lines: list[str], interim: Interim | None = None
) -> list[str]:
    """
    The verdict, the rule's criteria and the same criteria against ``also_against``, as Markdown lines. In an interim
    look (``interim``) the rule's outcome is named as on its seeds or envs only, not as the study's verdict.
    """
    outcome = f"On {interim.words()} only: {decision}" if interim else f"Verdict: {decision}"
    text = [
        f"**{outcome}.** The rule (`{study.path.as_posix()}`), stated {study.stated}, for {study.label(study.candidate)}:",
        "",
        *[f"- {line}" for line in lines],
    ]
    for other in study.also_against:
        text.append(f"- reported, not part of the rule, against {study.label(other)}:")
        for criterion in study.rule:
            ok, line = judge_criterion(study, runs, scores, {**criterion, "reference": other}, study.candidate)
            text.append(f"  - {'holds' if ok else 'does not hold' if ok is not None else 'open'}: {line}")
    return text


def report(study: Study, root: Path, out: Path, interim: Interim | None = None) -> str:
    """
    Write the study's tables, figures and verdict into ``out``; return the verdict. ``interim``: the seeds or envs
    ``study`` was narrowed to (:func:`seed_subset`, :func:`env_subset`), named in the table as an interim look.
    """
    runs, scores = study_runs(study, root)
    if study.candidates and study.candidate is None:  # a choice among candidates; with a `candidate`, a head-to-head
        decision = selection.report(study, runs, scores, out, command(study))
        plot_curves(study, runs, out)
        return decision
    out.mkdir(parents=True, exist_ok=True)
    decision, lines = verdict(study, runs, scores)
    interim_note = [interim.note(command(study)), ""] if interim else []
    if study.tables == "benchmark":
        options = argparse.Namespace(
            root=root,
            set=study.folder,
            out=out,
            last=study.final_evaluations,
            reps=study.reps_iqm,
            command=command(study, interim),
        )
        with labels_of(study.labels):  # the tables name algorithms as the verdict does
            plot.report(options, runs)
        if study.rule:
            header = f"<!-- Generated by {command(study, interim)}: do not edit by hand. -->"
            body = [*interim_note, *rule_lines(study, runs, scores, decision, lines, interim)]
            (out / "verdict.md").write_text("\n".join([header, f"# {study.name}: verdict", "", *body]) + "\n")
        return decision
    n_runs = sum(len(by_algo.get(algo, [])) for by_algo in runs.values() for algo in study.algos)
    text = [
        f"<!-- Generated by {command(study, interim)}: do not edit by hand. -->",
        f"# {study.name}: {n_runs} of {len(study.algos) * len(study.envs) * len(study.seeds)} runs",
        "",
        *interim_note,
        f"Seeds {', '.join(map(str, study.seeds))}; 95% intervals; in brackets after each cell, the runs it averages.",
        "",
        *rule_lines(study, runs, scores, decision, lines, interim),
    ]
    final_title = (
        "Final score (mean of the episodes played after training)"
        if study.final == "final_evaluation"
        else "Final return (mean of the last evaluations)"
    )
    text += ["", f"## {final_title}", "", *per_env_table(study, runs, scores, "final")]
    if study.published:
        text += ["", "## Published scores (agents not run here, for context)", "", *published_table(study)]
    text += ["", "## AUC (mean evaluation return over training)", "", *per_env_table(study, runs, scores, "auc")]
    for reference in difference_references(study):
        text += ["", f"## Final return minus {study.label(reference)}'s", "", *difference_table(study, scores, reference)]
    for measure in ("auc", "final"):
        iqms = iqm_intervals(study, runs, scores, measure)
        title = "AUC" if measure == "auc" else "final return"
        text += ["", f"## IQM of normalised {title} over the envs (algorithms with every run in)", ""]
        rows = [f"| {study.label(algo)} | {interval(iqms[algo], '.3f')} |" for algo in iqms]
        text += ["| algorithm | IQM |", "|---|---:|", *rows]
    resumed = [
        f"{study.label(algo)} on {env}, seed {run.seed} (at {', '.join(f'{step:,}' for step in run.resumed_at)})"
        for env, by_algo in runs.items()
        for algo, algo_runs in by_algo.items()
        for run in algo_runs
        if run.resumed_at
    ]
    if resumed:
        text += ["", f"Runs resumed from a checkpoint after an interruption (step): {'; '.join(resumed)}."]
    if study.normalisation == MINMAX:
        text += ["", "Normalisation (score - low) / (high - low), low and high per env over every run of the study there."]
    else:
        low_high = ", ".join(f"{env} [{low:g}, {high:g}]" for env, (low, high) in study.normalisation.items())
        text += ["", f"Normalisation (score - low) / (high - low), fixed before the runs: {low_high}."]
    (out / "table.md").write_text("\n".join(text) + "\n")
    plot_curves(study, runs, out)
    plot_aggregate(study, runs, scores, out)
    return decision


def plot_curves(study: Study, runs: dict, out: Path) -> None:
    envs = [env for env in study.envs if env in runs]
    if not envs:
        return
    colors = algo_colors(study.algos)
    # One legend below the panels, not over a panel's curves: rows of four, each row a quarter inch
    ncol = min(len(study.algos), 4)
    legend_rows = -(-len(study.algos) // ncol)
    height = 3.6 + 0.25 * legend_rows
    fig, axes = plt.subplots(1, len(envs), figsize=(4.2 * len(envs), height), squeeze=False)
    lines: dict[str, object] = {}
    counts: dict[str, int] = {}
    for ax, env in zip(axes[0], envs, strict=True):
        for algo, kept in runs[env].items():
            grid, curves = evaluation_curves(kept)
            mean, low, high = mean_ci(curves, study.reps_iqm)
            (line,) = ax.plot(grid, mean, color=colors.get(algo))
            ax.fill_between(grid, low, high, color=line.get_color(), alpha=0.2, linewidth=0)
            lines.setdefault(algo, line)
            counts[algo] = counts.get(algo, 0) + len(kept)
        ax.set(title=env, xlabel="Environment steps", ylabel="Evaluation return")
        ax.grid(alpha=0.3)
    labels = [f"{study.label(algo)} ({counts[algo]})" for algo in lines]
    fig.legend(list(lines.values()), labels, loc="lower center", ncol=ncol, fontsize=8, frameon=False)
    fig.suptitle(
        f"{study.name}: mean evaluation return over seeds, 95% bootstrap bands (runs over the envs in brackets)", fontsize=10
    )
    fig.tight_layout(rect=(0, (0.25 * legend_rows + 0.1) / height, 1, 1))
    fig.savefig(out / "curves.png", dpi=100)
    plt.close(fig)


def plot_aggregate(study: Study, runs: dict, scores: dict, out: Path) -> None:
    panels = [(measure, iqm_intervals(study, runs, scores, measure)) for measure in ("auc", "final")]
    if not any(iqms for _, iqms in panels):
        return
    colors = algo_colors(study.algos)
    fig, axes = plt.subplots(1, 2, figsize=(10, 0.6 * len(study.algos) + 1.6))
    for ax, (measure, iqms) in zip(axes, panels, strict=True):
        for row, (algo, (point, low, high)) in enumerate(iqms.items()):
            ax.barh(row, high - low, left=low, color=colors.get(algo), alpha=0.6, height=0.6)
            ax.plot([point, point], [row - 0.3, row + 0.3], color="black", linewidth=2)
        # Long labels (a candidate's settings) wrapped, or they take the panel's width
        ax.set_yticks(range(len(iqms)), [textwrap.fill(study.label(algo), 24) for algo in iqms], fontsize=8)
        ax.set_title(f"IQM of normalised {'AUC' if measure == 'auc' else 'final return'}", fontsize=10)
        ax.grid(axis="x", alpha=0.3)
    fig.suptitle(f"{study.name}: across {len(study.envs)} envs (95% stratified bootstrap CIs)", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "aggregate.png", dpi=100)
    plt.close(fig)


# ----------------------------------------------------------------------------------------------------------------------
# Setup check
# ----------------------------------------------------------------------------------------------------------------------
def setup_check(study: Study, root: Path, random_scores: dict) -> tuple[bool, list[str]]:
    """The setup check's algorithm above a random policy on every env: the interval of its final episodes' mean return
    (percentile bootstrap over episodes) above the random policy's interval. Returns whether it passed, a line per env."""
    check = study.setup_check or {}
    lines, passed = [], True
    for env in study.envs:
        for seed in check.get("seeds", []):
            folder = root / check["name"] / check["algo"] / f"{env_folder(env)}_{seed}"
            try:
                with np.load(folder / "evaluations.npz") as data:
                    episodes = data["results"][-study.final_evaluations :].ravel()
            except OSError:
                lines.append(f"{env} seed {seed}: not run")
                passed = False
                continue
            result = stats.bootstrap((episodes,), np.mean, n_resamples=study.reps_difference, method="percentile", rng=0)
            low, high = result.confidence_interval.low, result.confidence_interval.high
            random = random_scores[env]
            above = bool(low > random["high"])
            passed &= above
            lines.append(
                f"{env} seed {seed}: {study.label(check['algo'])} {episodes.mean():.2f} [{low:.2f}, {high:.2f}] "
                f"({len(episodes)} episodes) against random {random['mean']:.2f} [{random['low']:.2f}, {random['high']:.2f}]: "
                f"{'above' if above else 'NOT above'}"
            )
    return passed, lines


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("study", type=Path, help="the study file (benchmarks/<study>.yml)")
    parser.add_argument("--root", type=Path, default=Path("results/raw"), help="results root (default: results/raw)")
    parser.add_argument("--out", type=Path, default=None, help="report folder (default: results/<study name>)")
    parser.add_argument("--setup-check", action="store_true", help="judge the study's setup check instead")
    parser.add_argument("--random", type=Path, default=None, help="random policy's scores (scripts/random_policy.py)")
    parser.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=None,
        help="report on these of the study's seeds only, an interim look (default folder: results/<study>/seeds_<seeds>)",
    )
    parser.add_argument(
        "--envs",
        nargs="+",
        default=None,
        help="report on these of the study's envs only, an interim look (default folder: results/<study>/envs_<envs>)",
    )
    parser.add_argument(
        "--by-seed",
        action="store_true",
        help="print each of the candidate's runs (final / AUC) beside the references' on the same seed; writes nothing",
    )
    args = parser.parse_args(argv)
    study = Study.read(args.study)
    if args.by_seed:
        runs, scores = study_runs(study, args.root)
        print("\n".join(by_seed_table(study, runs, scores)))
        return "by seed"
    out = args.out or Path(study.out or Path("results") / study.name)
    if args.seeds or args.envs:
        if args.setup_check:
            parser.error("--seeds and --envs do not apply to --setup-check (its seeds and envs are the check's own)")
        narrowed = study
        try:
            if args.envs:
                narrowed = env_subset(narrowed, args.envs)
            if args.seeds:
                narrowed = seed_subset(narrowed, args.seeds)
        except ValueError as error:
            parser.error(str(error))
        # Named by the seeds asked for: a seed of one env's ``seeds_on`` only is not among the narrowed study's ``seeds``
        interim = Interim(seeds=sorted(set(args.seeds)) if args.seeds else None, envs=narrowed.envs if args.envs else None)
        out = args.out or out / interim.folder()
        decision = report(narrowed, args.root, out, interim)
        print(f"{study.name}, {interim.words()} only (interim): {decision}")
        return decision
    if args.setup_check:
        if args.random is None:
            parser.error("--setup-check needs --random")
        passed, lines = setup_check(study, args.root, json.loads(args.random.read_text())["results"])
        print("\n".join(lines))
        missing = sum(line.endswith(": not run") for line in lines)
        outcome = "passed" if passed else f"incomplete ({missing} runs missing)" if missing else "FAILED"
        print(f"Setup check: {outcome}")
        return "passed" if passed else "failed"
    decision = report(study, args.root, out)
    print(f"{study.name}: {decision}")
    return decision


if __name__ == "__main__":
    # A failed setup check is an error (a script that starts a grid after it stops there); a verdict is a result
    sys.exit(1 if main() == "failed" else 0)
