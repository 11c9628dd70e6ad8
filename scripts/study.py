"""
Judge and report a study stated as a file (``benchmarks/<study>.yml``): its tables, figures and verdict, from its runs.

A study file names what was run (``settings``: the hyperparameter set; ``algos``, ``envs``, ``seeds``; ``folder``: the
runs' folder under the results root, default its ``name``; ``run_names``: the name a study's algorithm carries on disk
where it differs, for runs made before a command-line name changed), how a run is scored (``final_evaluations``: the
evaluations averaged into the final return; the AUC is the mean evaluation return over training), the normalisation
of scores (``normalisation``: fixed ``[low, high]`` per env, or ``minmax``: per env over every run of the study's
algorithms there), the statistics (``confidence``, ``bootstrap_reps``), and, for a study that decides something, the
``rule``: criteria about its ``candidate``, each of one kind:

- ``final_not_below`` (``reference``): on every env, the upper bound of the interval of the candidate's mean final
  return minus the reference's is at least 0 (two-sample percentile bootstrap, the seeds of each side resampled apart);
- ``final_within`` (``reference``, ``margin``): on every env, the candidate's mean final return is at least the
  reference's minus ``margin`` times the env's range (``ranges``: ``[low, high]`` per env);
- ``iqm_above`` (``measure``: ``auc`` or ``final``; ``reference``): the candidate's IQM of normalised scores over every
  env and seed is above the reference's (point estimates; rliable's stratified bootstrap gives their intervals);
- ``auc_apart_above`` (``reference``, ``at_least``): on at least that many envs, the 95% interval of the candidate's
  mean AUC lies wholly above the reference's.

The verdict is "holds" when every criterion holds, "does not hold" otherwise, and "incomplete" while runs are missing.
``also_against`` lists the other algorithms the same criteria are reported for. The report (``tables``): ``study``
(the default) writes this script's tables and figures with the verdict in ``table.md``; ``benchmark`` writes
``scripts/plot.py``'s (per-env tables with steps to threshold, the paper's figures, aggregates) and the verdict, if the
study has a rule, in ``verdict.md``. A ``setup_check`` block (``algo``, ``seeds``, ``name``) is judged with
``--setup-check``: the algorithm's final evaluation episodes against a random policy's return (``--random``, from
``scripts/random_policy.py``).

Usage::

    python scripts/study.py benchmarks/minatar.yml                # tables, figures and verdict into results/minatar/
    python scripts/study.py benchmarks/minatar.yml --setup-check --random results/minatar/random_policy.json
"""

import argparse
import json
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
# run_stats.py sits next to this script: importable however the script is started
sys.path.insert(0, str(Path(__file__).resolve().parent))
import matplotlib.pyplot as plt
import numpy as np
import plot
import yaml
from benchmark import env_folder
from rliable import metrics
from run_stats import (
    Run,
    algo_order,
    evaluation_curves,
    interval_estimates,
    label,
    load_runs,
    mean_ci,
    mean_difference,
    mean_interval,
    normalised_matrices,
    position,
    run_scores,
    threshold,
    two_sample_ci,
)
from scipy import stats

COLORS = {"dqn": "tab:blue", "dqn_nstep": "tab:orange", "qrdqn": "tab:green", "offon_lambda_choice": "tab:red"}
MINMAX = "minmax"


@dataclass
class Study:
    """A study file, read."""

    path: Path
    name: str
    question: str
    algos: list[str]
    envs: list[str]
    seeds: list[int]
    normalisation: dict[str, tuple[float, float]] | str
    candidate: str | None = None
    rule: list[dict] = field(default_factory=list)
    final_evaluations: int = 3
    reps_difference: int = 10_000
    reps_iqm: int = 2_000
    also_against: list[str] = field(default_factory=list)
    setup_check: dict | None = None
    stated: str = ""
    folder: str = ""
    run_names: dict[str, str] = field(default_factory=dict)
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    tables: str = "study"
    # A study that chooses among candidates (scripts/selection.py): each with its algorithm, settings and runs' folder
    candidates: dict[str, dict] = field(default_factory=dict)
    judged: list[str] = field(default_factory=list)
    choose: dict | None = None
    seeds_on: dict[str, list[int]] = field(default_factory=dict)
    ceilings: dict[str, float] = field(default_factory=dict)
    out: str = ""
    labels: dict[str, str] = field(default_factory=dict)

    def label(self, algo: str) -> str:
        """The name tables give ``algo``: the study's own (``labels``), else the command-line name's usual one."""
        return self.labels.get(algo) or label(algo)

    def seeds_for(self, algo: str, env: str) -> list[int]:
        """The seeds ``algo`` is judged on on ``env``: its candidate's own, else the env's (``seeds_on``), else the study's."""
        own = self.candidates.get(algo, {}).get("seeds")
        return [int(seed) for seed in own] if own else self.seeds_on.get(env, self.seeds)

    def envs_for(self, algo: str) -> list[str]:
        return list(self.candidates.get(algo, {}).get("envs", self.envs))

    def source(self, algo: str, env: str) -> tuple[str, str]:
        """The folder (under the results root) and the algorithm name of ``algo``'s runs on ``env``."""
        candidate = self.candidates.get(algo)
        if candidate is None:
            return self.folder, self.run_names.get(algo, algo)
        folder = candidate.get("folder_on", {}).get(env, candidate.get("folder", self.folder))
        return folder, candidate.get("run_name", candidate["algo"])

    @classmethod
    def read(cls, path: Path) -> "Study":
        data = yaml.safe_load(path.read_text())
        reps = data.get("bootstrap_reps", {})
        normalisation = data.get("normalisation", MINMAX)
        if normalisation != MINMAX:
            normalisation = {env: (float(low), float(high)) for env, (low, high) in normalisation.items()}
        candidates = dict(data.get("candidates", {}))
        ranges = data.get("ranges", normalisation if normalisation != MINMAX else {})
        study = cls(
            path=path,
            name=data["name"],
            question=" ".join(data["question"].split()),
            algos=list(candidates) or list(data["algos"]),
            envs=list(data["envs"]),
            seeds=[int(seed) for seed in data["seeds"]],
            normalisation=normalisation,
            candidate=data.get("candidate"),
            rule=list(data.get("rule", [])),
            final_evaluations=int(data.get("final_evaluations", 3)),
            reps_difference=int(reps.get("difference", 10_000)),
            reps_iqm=int(reps.get("iqm", 2_000)),
            also_against=list(data.get("also_against", [])),
            setup_check=data.get("setup_check"),
            stated=str(data.get("stated", "")),
            folder=str(data.get("folder", data["name"])),
            run_names=dict(data.get("run_names", {})),
            ranges={env: (float(low), float(high)) for env, (low, high) in ranges.items()},
            tables=str(data.get("tables", "study")),
            candidates=candidates,
            judged=list(data.get("judged", [name for name in candidates if name not in data.get("references", [])])),
            choose=data.get("choose"),
            seeds_on={env: [int(seed) for seed in seeds] for env, seeds in data.get("seeds_on", {}).items()},
            ceilings={env: float(value) for env, value in data.get("ceilings", {}).items()},
            out=str(data.get("out", "")),
            labels=dict(data.get("labels", {})),
        )
        if study.tables not in ("study", "benchmark"):
            raise ValueError(f"{path}: tables must be 'study' or 'benchmark', not {study.tables!r}")
        if study.rule and not study.candidates and study.candidate not in study.algos:
            raise ValueError(f"{path}: the candidate {study.candidate!r} is not one of the algos {study.algos}")
        return study


# ----------------------------------------------------------------------------------------------------------------------
# Scores
# ----------------------------------------------------------------------------------------------------------------------
def study_runs(study: Study, root: Path) -> tuple[dict[str, dict[str, list[Run]]], dict[str, dict[str, dict]]]:
    """
    ``runs[env][algo]`` and ``scores[env][algo]`` (final, auc, steps, solved: one per run, by seed) of the study's
    finished runs, under the study's names for its algorithms; envs sorted, algorithms in ``run_stats``' table order
    (candidates in the file's order).
    """
    loaded: dict[str, dict] = {}
    runs: dict[str, dict[str, list[Run]]] = {}
    scores: dict[str, dict[str, dict]] = {}
    for env in sorted(study.envs):
        for algo in sorted(study.algos, key=algo_order) if not study.candidates else study.algos:
            if env not in study.envs_for(algo):
                continue
            folder, on_disk = study.source(algo, env)
            if folder not in loaded:
                loaded[folder] = load_runs(root / folder) if (root / folder).is_dir() else {}
            # Runs made under the algorithm's former name (``run_names``) and under its own
            names = dict.fromkeys([on_disk, algo])
            seeds = study.seeds_for(algo, env)
            found = [run for name in names for run in loaded[folder].get(env, {}).get(name, []) if run.seed in seeds]
            kept = sorted((replace(run, algo=algo) for run in found), key=lambda run: run.seed)
            if kept:
                grid, curves = evaluation_curves(kept)
                runs.setdefault(env, {})[algo] = kept
                scores.setdefault(env, {})[algo] = run_scores(kept, grid, curves, study.final_evaluations, threshold(env))
    return runs, scores


def complete(study: Study, runs: dict, env: str, algo: str) -> bool:
    """Whether every seed of ``algo`` on ``env`` has its finished run."""
    return len(runs.get(env, {}).get(algo, [])) == len(study.seeds_for(algo, env))


def missing_runs(study: Study, runs: dict) -> int:
    expected = sum(len(study.seeds_for(algo, env)) for algo in study.algos for env in study.envs_for(algo))
    return expected - sum(len(by_algo.get(algo, [])) for by_algo in runs.values() for algo in study.algos)


def normalised(study: Study, runs: dict, scores: dict, algo: str, measure: str) -> np.ndarray | None:
    """(seeds, envs) of normalised scores, envs sorted (the order every caller gives rliable); None if a run is missing."""
    envs = sorted(study.envs)
    if not all(complete(study, runs, env, algo) for env in envs):
        return None
    if study.normalisation == MINMAX:
        # Per env over every run of the study's algorithms there: only once every algorithm's runs are in
        if missing_runs(study, runs):
            return None
        return normalised_matrices(runs, scores, envs, list(study.algos))[measure][algo]
    columns = []
    for env in envs:
        low, high = study.normalisation[env]
        columns.append((scores[env][algo][measure] - low) / (high - low))
    return np.array(columns).T


def iqm_intervals(study: Study, runs: dict, scores: dict, measure: str) -> dict[str, tuple[float, float, float]]:
    """Per algorithm with every run in: the IQM of normalised ``measure`` over envs and seeds, with its interval."""
    matrices = {algo: normalised(study, runs, scores, algo, measure) for algo in study.algos}
    ready = {algo: matrix for algo, matrix in matrices.items() if matrix is not None}
    if not ready:
        return {}
    point, interval = interval_estimates(ready, lambda s: np.array([metrics.aggregate_iqm(s)]), study.reps_iqm)
    return {algo: (float(point[algo][0]), float(interval[algo][0, 0]), float(interval[algo][1, 0])) for algo in ready}


def final_difference(study: Study, scores: dict, env: str, algo: str, reference: str) -> tuple[float, float, float] | None:
    """The mean final return of ``algo`` minus ``reference``'s on ``env``, with its interval (None: a side is missing)."""
    by_algo = scores.get(env, {})
    if algo not in by_algo or reference not in by_algo:
        return None
    return two_sample_ci(by_algo[algo]["final"], by_algo[reference]["final"], mean_difference, study.reps_difference)


# ----------------------------------------------------------------------------------------------------------------------
# The rule
# ----------------------------------------------------------------------------------------------------------------------
def judge_criterion(study: Study, runs: dict, scores: dict, criterion: dict, algo: str) -> tuple[bool | None, str]:
    """Whether one criterion holds for ``algo`` (None: runs missing), and a line that says why."""
    kind, reference = criterion["kind"], criterion["reference"]
    envs = list(criterion.get("envs", study.envs))
    if kind == "final_not_below":
        return final_not_below(study, runs, scores, algo, reference, float(criterion.get("margin", 0.0)), envs)
    if kind == "iqm_above":
        measure = criterion["measure"]
        iqms = iqm_intervals(study, runs, scores, measure)
        name = f"IQM of normalised {measure.upper() if measure == 'auc' else measure}"
        if algo not in iqms or reference not in iqms:
            return None, f"{name} above {study.label(reference)}'s: runs missing"
        ours, theirs = iqms[algo], iqms[reference]
        return ours[0] > theirs[0], (
            f"{name} above {study.label(reference)}'s: {ours[0]:.3f} [{ours[1]:.3f}, {ours[2]:.3f}] against "
            f"{theirs[0]:.3f} [{theirs[1]:.3f}, {theirs[2]:.3f}]"
        )
    if kind == "final_within":
        return final_within(study, runs, scores, algo, reference, float(criterion["margin"]), envs)
    if kind == "mean_above":
        return mean_above(study, runs, scores, algo, reference, criterion.get("measure", "auc"), envs)
    if kind == "auc_apart_above":
        return auc_apart_above(study, runs, scores, algo, reference, int(criterion["at_least"]))
    raise ValueError(f"unknown criterion kind {kind!r} in the rule")


def complete_pair(study: Study, runs: dict, env: str, algo: str, reference: str) -> bool:
    return complete(study, runs, env, algo) and complete(study, runs, env, reference)


def final_not_below(
    study: Study, runs: dict, scores: dict, algo: str, reference: str, margin: float, envs: list[str]
) -> tuple[bool | None, str]:
    """On every env, the upper bound of the interval of (``algo`` - reference) mean final return at least minus
    ``margin`` times the env's range (0: not below zero)."""
    text = f"final return not below {study.label(reference)}'s on any env by the interval of the difference"
    if margin:
        text += f" by more than {margin:g} of the env's range"
    below, cells = [], []
    for env in envs:
        difference = final_difference(study, scores, env, algo, reference)
        if difference is None or not complete_pair(study, runs, env, algo, reference):
            return None, f"{text}: runs missing on {env}"
        cells.append(f"{env} {interval(difference, '+.3g')}")
        low, high = study.ranges.get(env, (0.0, 0.0))
        if difference[2] < -margin * (high - low):
            below.append(f"{env} ({difference[0]:+.2f} [{difference[1]:+.2f}, {difference[2]:+.2f}])")
    if margin:
        text += f" ({'; '.join(cells)})"
    return not below, f"{text}: {'below on ' + ', '.join(below) if below else 'holds on every env'}"


def final_within(
    study: Study, runs: dict, scores: dict, algo: str, reference: str, margin: float, envs: list[str]
) -> tuple[bool | None, str]:
    """
    On every env, ``algo``'s mean final return at least the reference's minus ``margin`` times the env's range. With
    runs missing, an env fails already where the mean would stay below the bar even if every missing run ended at the
    env's ceiling (``ceilings``: the highest return an episode can have there); otherwise it waits.
    """
    text = f"final return at least {study.label(reference)}'s minus {margin:g} of the env's range on every env"
    below, bars, waiting = [], [], []
    for env in envs:
        if not complete(study, runs, env, reference):
            return None, f"{text}: runs missing on {env}"
        low, high = study.ranges[env]
        theirs = float(np.mean(scores[env][reference]["final"]))
        bar = theirs - margin * (high - low)
        finals = scores.get(env, {}).get(algo, {}).get("final", np.zeros(0))
        missing = len(study.seeds_for(algo, env)) - len(finals)
        if missing and env not in study.ceilings:
            waiting.append(env)
            continue
        best = (finals.sum() + missing * study.ceilings.get(env, 0.0)) / len(study.seeds_for(algo, env))
        ours = float(np.mean(finals)) if len(finals) else np.nan
        bars.append(f"{env} {ours:.1f} against the bar {bar:.1f} ({study.label(reference)} {theirs:.1f})")
        if best < bar:
            below.append(env + (f" (out of reach with {missing} runs missing)" if missing else ""))
        elif missing:
            waiting.append(env)
    line = f"{text}: {'; '.join(bars)}" + (f"; below on {', '.join(below)}" if below else "")
    if below:
        return False, line
    return (None, f"{line}; runs missing on {', '.join(waiting)}") if waiting else (True, line)


def mean_above(
    study: Study, runs: dict, scores: dict, algo: str, reference: str, measure: str, envs: list[str]
) -> tuple[bool | None, str]:
    """``algo``'s mean over ``envs`` of its normalised mean ``measure`` above the reference's."""
    text = f"mean normalised {measure.upper() if measure == 'auc' else measure} above {study.label(reference)}'s"
    if not all(complete(study, runs, env, name) for env in envs for name in (algo, reference)):
        return None, f"{text}: runs missing"
    ours, theirs = (mean_normalised(study, scores, name, measure, envs) for name in (algo, reference))
    return ours > theirs, f"{text}: {ours:.3f} against {theirs:.3f}"


def mean_normalised(study: Study, scores: dict, algo: str, measure: str, envs: list[str]) -> float:
    """The mean over ``envs`` of ``algo``'s mean ``measure`` there, normalised with the study's fixed ranges."""
    values = []
    for env in envs:
        low, high = study.ranges[env]
        values.append((float(np.mean(scores[env][algo][measure])) - low) / (high - low))
    return float(np.mean(values))


def auc_apart_above(
    study: Study, runs: dict, scores: dict, algo: str, reference: str, at_least: int
) -> tuple[bool | None, str]:
    """On at least ``at_least`` envs, the 95% interval of ``algo``'s mean AUC lies above the reference's, apart."""
    text = f"AUC interval above {study.label(reference)}'s, apart, on at least {at_least} envs"
    apart, cells = 0, []
    for env in study.envs:
        if not complete_pair(study, runs, env, algo, reference):
            return None, f"{text}: runs missing on {env}"
        ours = mean_interval(scores[env][algo]["auc"], study.reps_iqm)
        theirs = mean_interval(scores[env][reference]["auc"], study.reps_iqm)
        where = position(ours, theirs)
        apart += where == "above, apart"
        cells.append(f"{env} [{ours[0]:.1f}, {ours[1]:.1f}] against [{theirs[0]:.1f}, {theirs[1]:.1f}] ({where})")
    return apart >= at_least, f"{text}: on {apart}; " + "; ".join(cells)


def verdict(study: Study, runs: dict, scores: dict) -> tuple[str, list[str]]:
    """The study's verdict ("holds", "does not hold", "incomplete"; "no rule" for a study that decides nothing) and a
    line per criterion."""
    if not study.rule:
        return "no rule", []
    results = [judge_criterion(study, runs, scores, criterion, study.candidate) for criterion in study.rule]
    lines = [f"{'holds' if ok else 'does not hold' if ok is not None else 'open'}: {text}" for ok, text in results]
    missing = missing_runs(study, runs)
    if missing or any(ok is None for ok, _ in results):
        return f"incomplete ({missing} runs missing)", lines
    return ("holds" if all(ok for ok, _ in results) else "does not hold"), lines


# ----------------------------------------------------------------------------------------------------------------------
# Report: tables and figures
# ----------------------------------------------------------------------------------------------------------------------
def interval(values: tuple[float, float, float], spec: str = ".2f") -> str:
    point, low, high = values
    return f"{point:{spec}} (one run)" if np.isnan(low) else f"{point:{spec}} [{low:{spec}}, {high:{spec}}]"


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


def difference_table(study: Study, scores: dict) -> list[str]:
    others = [algo for algo in study.algos if algo != "dqn"]
    lines = [f"| env | {' | '.join(f'{study.label(algo)} - DQN' for algo in others)} |", "|---|" + "---:|" * len(others)]
    for env in study.envs:
        cells = []
        for algo in others:
            difference = final_difference(study, scores, env, algo, "dqn")
            cells.append("-" if difference is None else interval(difference, "+.2f"))
        lines.append(f"| {env} | {' | '.join(cells)} |")
    return lines


def command(study: Study) -> str:
    return f"python scripts/study.py {study.path.as_posix()}"


def rule_lines(study: Study, runs: dict, scores: dict, decision: str, lines: list[str]) -> list[str]:
    """The verdict, the rule's criteria and the same criteria against ``also_against``, as Markdown lines."""
    text = [
        f"**Verdict: {decision}.** The rule (`{study.path.as_posix()}`), stated {study.stated}, for "
        f"{study.label(study.candidate)}:",
        "",
        *[f"- {line}" for line in lines],
    ]
    for other in study.also_against:
        text.append(f"- reported, not part of the rule, against {study.label(other)}:")
        for criterion in study.rule:
            ok, line = judge_criterion(study, runs, scores, {**criterion, "reference": other}, study.candidate)
            text.append(f"  - {'holds' if ok else 'does not hold' if ok is not None else 'open'}: {line}")
    return text


def report(study: Study, root: Path, out: Path) -> str:
    """Write the study's tables, figures and verdict into ``out``; return the verdict."""
    runs, scores = study_runs(study, root)
    if study.candidates:
        import selection  # a study that chooses among candidates (selection.py imports this module)

        return selection.report(study, runs, scores, out, command(study))
    out.mkdir(parents=True, exist_ok=True)
    decision, lines = verdict(study, runs, scores)
    if study.tables == "benchmark":
        options = argparse.Namespace(
            root=root, set=study.folder, out=out, last=study.final_evaluations, reps=study.reps_iqm, command=command(study)
        )
        plot.report(options, runs)
        if study.rule:
            header = f"<!-- Generated by {command(study)}: do not edit by hand. -->"
            body = rule_lines(study, runs, scores, decision, lines)
            (out / "verdict.md").write_text("\n".join([header, f"# {study.name}: verdict", "", *body]) + "\n")
        return decision
    n_runs = sum(len(by_algo.get(algo, [])) for by_algo in runs.values() for algo in study.algos)
    text = [
        f"<!-- Generated by {command(study)}: do not edit by hand. -->",
        f"# {study.name}: {n_runs} of {len(study.algos) * len(study.envs) * len(study.seeds)} runs",
        "",
        f"Seeds {', '.join(map(str, study.seeds))}; 95% intervals; in brackets after each cell, the runs it averages.",
        "",
        *rule_lines(study, runs, scores, decision, lines),
    ]
    text += ["", "## Final return (mean of the last evaluations)", "", *per_env_table(study, runs, scores, "final")]
    text += ["", "## AUC (mean evaluation return over training)", "", *per_env_table(study, runs, scores, "auc")]
    text += ["", "## Final return minus DQN's", "", *difference_table(study, scores)]
    for measure in ("auc", "final"):
        iqms = iqm_intervals(study, runs, scores, measure)
        title = "AUC" if measure == "auc" else "final return"
        text += ["", f"## IQM of normalised {title} over the envs (algorithms with every run in)", ""]
        rows = [f"| {study.label(algo)} | {interval(iqms[algo], '.3f')} |" for algo in iqms]
        text += ["| algorithm | IQM |", "|---|---:|", *rows]
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
    fig, axes = plt.subplots(1, len(envs), figsize=(4.2 * len(envs), 3.6), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        for algo, kept in runs[env].items():
            grid, curves = evaluation_curves(kept)
            mean, low, high = mean_ci(curves, study.reps_iqm)
            ax.plot(grid, mean, color=COLORS.get(algo), label=f"{study.label(algo)} ({len(kept)})")
            ax.fill_between(grid, low, high, color=COLORS.get(algo), alpha=0.2, linewidth=0)
        ax.set(title=env, xlabel="Environment steps", ylabel="Evaluation return")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"{study.name}: mean evaluation return over seeds, 95% bootstrap bands (runs in brackets)", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=100)
    plt.close(fig)


def plot_aggregate(study: Study, runs: dict, scores: dict, out: Path) -> None:
    panels = [(measure, iqm_intervals(study, runs, scores, measure)) for measure in ("auc", "final")]
    if not any(iqms for _, iqms in panels):
        return
    fig, axes = plt.subplots(1, 2, figsize=(9, 0.6 * len(study.algos) + 1.6))
    for ax, (measure, iqms) in zip(axes, panels, strict=True):
        for row, (algo, (point, low, high)) in enumerate(iqms.items()):
            ax.barh(row, high - low, left=low, color=COLORS.get(algo), alpha=0.6, height=0.6)
            ax.plot([point, point], [row - 0.3, row + 0.3], color="black", linewidth=2)
        ax.set_yticks(range(len(iqms)), [study.label(algo) for algo in iqms])
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
    args = parser.parse_args(argv)
    study = Study.read(args.study)
    if args.setup_check:
        if args.random is None:
            parser.error("--setup-check needs --random")
        passed, lines = setup_check(study, args.root, json.loads(args.random.read_text())["results"])
        print("\n".join(lines))
        missing = sum(line.endswith(": not run") for line in lines)
        outcome = "passed" if passed else f"incomplete ({missing} runs missing)" if missing else "FAILED"
        print(f"Setup check: {outcome}")
        return "passed" if passed else "failed"
    decision = report(study, args.root, args.out or Path(study.out or Path("results") / study.name))
    print(f"{study.name}: {decision}")
    return decision


if __name__ == "__main__":
    # A failed setup check is an error (a script that starts a grid after it stops there); a verdict is a result
    sys.exit(1 if main() == "failed" else 0)
