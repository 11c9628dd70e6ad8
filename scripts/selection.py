"""
A study that chooses among candidates (``candidates`` in its file), as the search chose OffOnDQN's settings.

Each candidate is an algorithm with its settings (``algo``, ``hyperparams``, ``per_env``) and the folder of its runs;
``references`` are candidates that are reported and compared with, not judged. Every judged candidate is held to the
study's ``rule`` (the criteria of ``scripts/study.py``, about that candidate): "yes" when every criterion holds, "no"
as soon as one fails, "pending" while runs are missing. ``choose`` then picks, among the candidates that pass, the one
with the highest mean over ``envs`` of the normalised mean ``measure`` (fixed ``normalisation`` ranges), and says
whether it is above each of ``against``; the choice waits until every judged candidate is decided. With ``per_env``,
it picks on each env the candidate with the highest mean ``measure`` instead (no rule: the n of n-step DQN). With
``pairs`` (``{candidate: reference}``, an option against its absence), it says on each env whether the candidate is
taken: its mean normalised AUC and mean final return both above the reference's, and the 95% interval of the
difference of mean final returns wholly above 0 (prioritised replay's first look).

``scripts/study.py`` calls :func:`report` for such a study; its table goes to ``<out>/<study name>.md``.
"""

from pathlib import Path

import numpy as np
from rule import complete, final_difference, interval, judge_criterion, mean_normalised
from run_stats import label, mean_ci
from study_file import Study


def span(seeds: list[int]) -> str:
    """``30-34`` for consecutive seeds, else the list."""
    seeds = sorted(int(seed) for seed in seeds)
    consecutive = seeds == list(range(seeds[0], seeds[-1] + 1))
    return f"{seeds[0]}-{seeds[-1]}" if consecutive and len(seeds) > 1 else ", ".join(map(str, seeds))


def cell(scores: dict, env: str, name: str) -> str:
    """``final / AUC (runs)`` of a candidate's finished runs on ``env``, as the search's record has always shown them."""
    values = scores.get(env, {}).get(name)
    if values is None:
        return "—"
    return f"{np.mean(values['final']):.3g} / {np.mean(values['auc']):.3g} ({len(values['final'])})"


def judge(study: Study, runs: dict, scores: dict, name: str) -> tuple[str, list[str]]:
    """A candidate against the rule: "yes", "no: <criteria>" or "pending", and a line per criterion."""
    results = [judge_criterion(study, runs, scores, criterion, name) for criterion in study.rule]
    lines = [f"{'holds' if ok else 'does not hold' if ok is not None else 'open'}: {text}" for ok, text in results]
    failed = [criterion["kind"] for criterion, (ok, _) in zip(study.rule, results, strict=True) if ok is False]
    if failed:
        return f"no: {', '.join(failed)}", lines
    return ("yes" if all(ok for ok, _ in results) else "pending"), lines


def mean_measure(study: Study, runs: dict, scores: dict, name: str) -> float:
    """The candidate's mean normalised ``choose`` measure over ``choose``'s envs, over its finished runs (NaN while an
    env has none); only complete candidates are chosen from (:func:`judge`)."""
    envs = study.choose.get("envs", study.envs)
    if not all(name in scores.get(env, {}) for env in envs):
        return np.nan
    return mean_normalised(study, scores, name, study.choose.get("measure", "auc"), envs)


def choice(study: Study, runs: dict, scores: dict, verdicts: dict[str, str]) -> str:
    """The choice: the highest mean normalised measure among the candidates that pass; "none"; or "pending"."""
    pending = [name for name in study.judged if verdicts[name] == "pending"]
    if pending:
        return f"pending ({len(study.judged) - len(pending)} of {len(study.judged)} candidates decided)"
    passed = sorted((mean_measure(study, runs, scores, name), name) for name in study.judged if verdicts[name] == "yes")
    if not passed:
        return "none"
    value, name = passed[-1]
    against = []
    for other in study.choose.get("against", []):
        theirs = mean_measure(study, runs, scores, other)
        against.append(f"{'above' if value > theirs else 'not above'} {other}'s {theirs:.3f}")
    return f"{name}, {value:.3f}" + (f", {', '.join(against)}" if against else "")


def per_env_choice(study: Study, runs: dict, scores: dict) -> list[str]:
    """One row per env: each candidate's cell and the one with the highest mean ``measure`` there."""
    measure = study.choose.get("measure", "auc")
    lines = [
        "| Env | " + " | ".join(f"{name} final / AUC (n)" for name in study.judged) + " | Chosen |",
        "|---|" + "---|" * (len(study.judged) + 1),
    ]
    for env in study.envs:
        ready = all(complete(study, runs, env, name) for name in study.judged)
        best = max(study.judged, key=lambda name: float(np.mean(scores[env][name][measure]))) if ready else "pending"
        lines.append(f"| {env} | " + " | ".join(cell(scores, env, name) for name in study.judged) + f" | {best} |")
    return lines


def mean_with_interval(study: Study, scores: dict, env: str, name: str, measure: str) -> str:
    """A candidate's mean ``measure`` on ``env`` over its finished runs, with its 95% bootstrap interval, and the count."""
    values = scores.get(env, {}).get(name)
    if values is None:
        return "—"
    point, low, high = mean_ci(np.asarray(values[measure]), study.reps_difference)
    return f"{interval((float(point[0]), float(low[0]), float(high[0])))} ({len(values[measure])})"


def paired_choice(study: Study, runs: dict, scores: dict) -> tuple[str, list[str]]:
    """One row per pair and env: both sides' final return and AUC, the difference of final returns, and whether the
    candidate is taken there (see the module's docstring); the decision lists the envs where it is."""
    lines = [
        "| Candidate | Against | Env | Final return | Reference's | Difference | AUC | Reference's | Taken |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    taken, pending = [], 0
    for name, reference in study.choose["pairs"].items():
        for env in study.envs_for(name):
            ready = complete(study, runs, env, name) and complete(study, runs, env, reference)
            difference = final_difference(study, scores, env, name, reference) if ready else None
            if difference is None:
                verdict, pending = "pending", pending + 1
            else:
                ours, theirs = scores[env][name], scores[env][reference]
                above = all(np.mean(ours[key]) > np.mean(theirs[key]) for key in ("final", "auc"))
                verdict = "yes" if above and difference[1] > 0 else "no"
                if verdict == "yes":
                    taken.append(f"{name} on {env}")
            cells = [
                mean_with_interval(study, scores, env, side, measure)
                for measure in ("final", "auc")
                for side in (name, reference)
            ]
            final, final_ref, auc, auc_ref = cells
            difference_text = interval(difference) if difference is not None else "—"
            lines.append(
                f"| {name} | {reference} | {env} | {final} | {final_ref} | {difference_text} | {auc} | {auc_ref} | {verdict} |"
            )
    decision = f"pending ({pending} env pairs without all their runs)" if pending else (", ".join(taken) or "none")
    return decision, lines


def report(study: Study, runs: dict, scores: dict, out: Path, command: str) -> str:
    """Write ``<out>/<name>.md``: every candidate, whether it passes and why, and the choice; return the choice."""
    own = [
        f"{name} on seeds {span(study.candidates[name]['seeds'])}"
        for name in study.algos
        if study.candidates[name].get("seeds")
    ]
    own += [f"{env} on seeds {span(seeds)}" for env, seeds in study.seeds_on.items()]
    text = [
        f"<!-- Generated by {command}: do not edit by hand. -->",
        f"# {study.name}",
        "",
        study.question,
        "",
        f"Seeds {span(study.seeds)}{' (' + '; '.join(own) + ')' if own else ''}; the candidates and the rule stated "
        f"{study.stated} (`{study.path.as_posix()}`). "
        f"Final return: mean of the last {study.final_evaluations} evaluations; AUC: mean evaluation return over "
        "training; each cell the mean over the finished runs (their count in brackets).",
        "",
    ]
    if study.choose and study.choose.get("per_env"):
        decision = "per env"
        text += per_env_choice(study, runs, scores)
    elif study.choose and study.choose.get("pairs"):
        decision, lines = paired_choice(study, runs, scores)
        text += lines
        text += [
            "",
            f"**Taken: {decision}** (mean AUC and mean final return above the reference's, and the 95% interval "
            "of the difference of mean final returns wholly above 0; means with 95% bootstrap intervals, the runs' "
            "count in brackets)",
        ]
    else:
        envs = study.choose.get("envs", study.envs)
        verdicts, details = {}, {}
        for name in study.judged:
            verdicts[name], details[name] = judge(study, runs, scores, name)
        decision = choice(study, runs, scores, verdicts)
        measure = study.choose.get("measure", "auc")
        text += [
            "| Candidate | Settings | "
            + " | ".join(f"{env} final / AUC (n)" for env in study.envs)
            + f" | Mean normalised {measure.upper() if measure == 'auc' else measure} ({len(envs)} envs) | Passes |",
            "|---|---|" + "---|" * len(study.envs) + "---|---|",
        ]
        for name in study.algos:
            cells = " | ".join(cell(scores, env, name) for env in study.envs)
            value = mean_measure(study, runs, scores, name)
            passes = verdicts.get(name, "(reference)")
            description = study.candidates[name].get("description", "")
            text.append(f"| {name} | {description} | {cells} | {value:.3f} | {passes} |")
        rule = "; ".join(
            f"{criterion['kind']} against {label(criterion['reference'])}" + (f" ({k})" if (k := extras(criterion)) else "")
            for criterion in study.rule
        )
        basis = f"the highest mean among the candidates that pass the rule: {rule}" if rule else "the highest mean"
        text += ["", f"**Choice: {decision}** ({basis})"]
        if study.rule:
            text += ["", "Why each candidate passes or not:", ""]
            for name in study.judged:
                text += [f"- {name}:", *[f"  - {line}" for line in details[name]]]
    if isinstance(study.normalisation, dict):
        ranges = ", ".join(f"{env} [{low:g}, {high:g}]" for env, (low, high) in study.normalisation.items())
        text += ["", f"Normalisation (score - low) / (high - low), fixed before the runs: {ranges}."]
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{study.name}.md").write_text("\n".join(text) + "\n")
    return decision


def extras(criterion: dict) -> str:
    """A criterion's parameters other than its kind and reference, as ``key value`` pairs."""
    return ", ".join(f"{key} {value}" for key, value in criterion.items() if key not in ("kind", "reference"))
