"""
A study's runs scored, and its rule judged on them.

Each criterion of a study's ``rule`` is of one kind:

- ``final_not_below`` (``reference``): on every env, the upper bound of the interval of the candidate's mean final
  return minus the reference's is at least 0 (two-sample percentile bootstrap, the seeds of each side resampled apart);
- ``auc_not_below`` (``reference``): the same on the mean AUC (the mean of a run's evaluations);
- ``final_within`` (``reference``, ``margin``): on every env, the candidate's mean final return is at least the
  reference's minus ``margin`` times the env's range (``ranges``: ``[low, high]`` per env);
- ``iqm_above`` (``measure``: ``auc`` or ``final``; ``reference``): the candidate's IQM of normalised scores over every
  env and seed is above the reference's (point estimates; rliable's stratified bootstrap gives their intervals);
- ``mean_above`` (``reference``, ``measure``, optional ``margin``): the candidate's mean over envs of its normalised mean
  score is above the reference's minus ``margin`` (default 0: above it);
- ``auc_apart_above`` (``reference``, ``at_least``): on at least that many envs, the 95% interval of the candidate's
  mean AUC lies wholly above the reference's.

The verdict is "holds" when every criterion holds, "does not hold" otherwise, and "incomplete" while runs the rule reads
are missing (:func:`rule_algos`: those of other algorithms, reported against but not judged by, cannot change it).
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
from rliable import metrics
from run_stats import (
    Run,
    algo_order,
    evaluation_curves,
    interval_estimates,
    load_runs,
    mean_difference,
    mean_interval,
    normalised_matrices,
    position,
    run_scores,
    threshold,
    two_sample_ci,
)
from study_file import MINMAX, Study


def study_runs(study: Study, root: Path) -> tuple[dict[str, dict[str, list[Run]]], dict[str, dict[str, dict]]]:
    """
    ``runs[env][algo]`` and ``scores[env][algo]`` (final, auc, steps, solved: one per run, by seed) of the study's
    finished runs, under the study's names for its algorithms; envs sorted, algorithms in ``run_stats``' table order
    (candidates in the file's order).
    """
    loaded: dict[str, dict] = {}
    runs: dict[str, dict[str, list[Run]]] = {}
    scores: dict[str, dict[str, dict]] = {}
    after_training = study.final == "final_evaluation"  # final return: the episodes played after training
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
                scores.setdefault(env, {})[algo] = run_scores(
                    kept, grid, curves, study.final_evaluations, threshold(env), after_training=after_training
                )
    return runs, scores


def complete(study: Study, runs: dict, env: str, algo: str) -> bool:
    """Whether every seed of ``algo`` on ``env`` has its finished run."""
    return len(runs.get(env, {}).get(algo, [])) == len(study.seeds_for(algo, env))


def missing_runs(study: Study, runs: dict, algos: list[str] | None = None) -> int:
    """How many runs of ``algos`` (default: every algorithm of the study) are not in ``runs``."""
    algos = list(study.algos) if algos is None else algos
    expected = sum(len(study.seeds_for(algo, env)) for algo in algos for env in study.envs_for(algo))
    return expected - sum(len(by_algo.get(algo, [])) for by_algo in runs.values() for algo in algos)


def rule_algos(study: Study) -> list[str]:
    """
    The algorithms whose runs the rule reads: the candidate and its criteria's references; every algorithm of the
    study where the normalisation is taken over all their runs (``minmax``). The verdict waits for these runs only:
    the others' (``also_against``) cannot change it.
    """
    if study.normalisation == MINMAX:
        return list(study.algos)
    return list(dict.fromkeys([study.candidate, *(criterion["reference"] for criterion in study.rule)]))


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


def final_difference(
    study: Study, scores: dict, env: str, algo: str, reference: str, measure: str = "final"
) -> tuple[float, float, float] | None:
    """
    The mean final return (or ``measure``: ``auc``) of ``algo`` minus ``reference``'s on ``env``, with its interval
    (None: a side is missing).
    """
    by_algo = scores.get(env, {})
    if algo not in by_algo or reference not in by_algo:
        return None
    return two_sample_ci(by_algo[algo][measure], by_algo[reference][measure], mean_difference, study.reps_difference)


# ----------------------------------------------------------------------------------------------------------------------
# The rule
# ----------------------------------------------------------------------------------------------------------------------
# The criteria "not below the reference on every env, by the interval of the difference", and what each compares
NOT_BELOW_MEASURES = {"final_not_below": "final", "auc_not_below": "auc"}


def judge_criterion(study: Study, runs: dict, scores: dict, criterion: dict, algo: str) -> tuple[bool | None, str]:
    """Whether one criterion holds for ``algo`` (None: runs missing), and a line that says why."""
    kind, reference = criterion["kind"], criterion["reference"]
    envs = list(criterion.get("envs", study.envs))
    if kind in NOT_BELOW_MEASURES:
        margin, measure = float(criterion.get("margin", 0.0)), NOT_BELOW_MEASURES[kind]
        return final_not_below(study, runs, scores, algo, reference, margin, envs, measure)
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
        margin = float(criterion.get("margin", 0.0))
        return mean_above(study, runs, scores, algo, reference, criterion.get("measure", "auc"), envs, margin)
    if kind == "auc_apart_above":
        return auc_apart_above(study, runs, scores, algo, reference, int(criterion["at_least"]))
    raise ValueError(f"unknown criterion kind {kind!r} in the rule")


def complete_pair(study: Study, runs: dict, env: str, algo: str, reference: str) -> bool:
    return complete(study, runs, env, algo) and complete(study, runs, env, reference)


def final_not_below(
    study: Study,
    runs: dict,
    scores: dict,
    algo: str,
    reference: str,
    margin: float,
    envs: list[str],
    measure: str = "final",
) -> tuple[bool | None, str]:
    """On every env, the upper bound of the interval of (``algo`` - reference) mean final return (or ``measure``:
    ``auc``) at least minus ``margin`` times the env's range (0: not below zero)."""
    what = "final return" if measure == "final" else "AUC"
    text = f"{what} not below {study.label(reference)}'s on any env by the interval of the difference"
    if margin:
        text += f" by more than {margin:g} of the env's range"
    below, cells = [], []
    for env in envs:
        difference = final_difference(study, scores, env, algo, reference, measure)
        if difference is None or not complete_pair(study, runs, env, algo, reference):
            return None, f"{text}: runs missing on {env}"
        if np.isnan(difference[2]):
            # A side with a single run has no interval: the criterion cannot be judged, not passed by a NaN comparison
            return None, f"{text}: no interval on {env} (a side has a single run)"
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
    study: Study, runs: dict, scores: dict, algo: str, reference: str, measure: str, envs: list[str], margin: float = 0.0
) -> tuple[bool | None, str]:
    """``algo``'s mean over ``envs`` of its normalised mean ``measure`` above the reference's minus ``margin``."""
    text = f"mean normalised {measure.upper() if measure == 'auc' else measure} above {study.label(reference)}'s"
    if margin:
        text += f" minus {margin:g}"
    if not all(complete(study, runs, env, name) for env in envs for name in (algo, reference)):
        return None, f"{text}: runs missing"
    ours, theirs = (mean_normalised(study, scores, name, measure, envs) for name in (algo, reference))
    return ours > theirs - margin, f"{text}: {ours:.3f} against {theirs:.3f}"


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
    missing = missing_runs(study, runs, rule_algos(study))
    if missing or any(ok is None for ok, _ in results):
        return f"incomplete ({missing} runs missing)", lines
    return ("holds" if all(ok for ok, _ in results) else "does not hold"), lines


def interval(values: tuple[float, float, float], spec: str = ".2f") -> str:
    point, low, high = values
    return f"{point:{spec}} (one run)" if np.isnan(low) else f"{point:{spec}} [{low:{spec}}, {high:{spec}}]"
