"""
A study file (``benchmarks/<study>.yml``), read: what its runs are and how they are judged.

The runner (``scripts/benchmark.py --study``) and the reporter (``scripts/study.py``) both read a study through
:class:`Study`, so that a candidate's seeds, folder and settings are resolved in one place. This module needs only
YAML: the runner imports it without the plotting and statistics libraries.

A study file names what was run (``settings``: the hyperparameter set; ``algos``, ``envs``, ``seeds``; ``folder``: the
runs' folder under the results root, default its ``name``; ``run_names``: the name a study's algorithm carries on disk
where it differs, for runs made before a command-line name changed; ``device``; ``evaluation``: ``every`` env steps,
``episodes`` each, ``episodes_on`` per env), how a run is scored (``final_evaluations``: the evaluations averaged into
the final return, or ``final: final_evaluation``: the episodes a run played after training, its final_evaluation.npz; the
AUC is the mean evaluation return over training; ``published``: other agents' published scores per env, reported
beside), the normalisation of scores
(``normalisation``: fixed ``[low, high]`` per env, or ``minmax``: per env over every run of the study's algorithms
there), the statistics (``confidence``, ``bootstrap_reps``), and, for a study that decides something, the ``rule``
about its ``candidate`` (its criteria: ``scripts/rule.py``). A study that chooses among ``candidates`` gives each its
``algo``, ``hyperparams``, ``per_env`` settings, ``envs``, ``seeds`` (else ``seeds_on`` per env, else the study's),
``folder`` (``folder_on`` per env) and ``run_name``. A study with ``candidates`` and a ``candidate`` among them is a
head-to-head of configurations: the candidate is judged by the rule against the others, wherever their runs are (a
configuration of its own against runs of other studies' folders).
"""

from dataclasses import dataclass, field
from pathlib import Path

import yaml

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
    # Where a run's final return comes from: "evaluations" (the mean of its last ``final_evaluations`` evaluations) or
    # "final_evaluation" (its final_evaluation.npz: the episodes played after training, as the Atari 100k protocol scores)
    final: str = "evaluations"
    # Published scores per env of agents not run here, reported beside the study's: {agent: {env: score}}
    published: dict[str, dict[str, float]] = field(default_factory=dict)
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
    # What the runner needs besides: the hyperparameter set, the torch device, the evaluation
    settings: str = "tuned"
    device: str | None = None
    evaluation_every: int | None = None
    evaluation_episodes: int | None = None
    episodes_on: dict[str, int] = field(default_factory=dict)

    def label(self, algo: str) -> str:
        """The name tables give ``algo``: the study's own (``labels``), else the command-line name's usual one."""
        # Imported here: the runner reads study files without the statistics libraries, and never labels
        from run_stats import label

        return self.labels.get(algo) or label(algo)

    def seeds_for(self, algo: str, env: str) -> list[int]:
        """The seeds ``algo`` is judged on on ``env``: its candidate's own, else the env's (``seeds_on``), else the study's."""
        own = self.candidates.get(algo, {}).get("seeds")
        return [int(seed) for seed in own] if own else self.seeds_on.get(env, self.seeds)

    def envs_for(self, algo: str) -> list[str]:
        return list(self.candidates.get(algo, {}).get("envs", self.envs))

    def algo_of(self, name: str) -> str:
        """The command-line algorithm a study's name trains: a candidate's ``algo``, else the name itself."""
        return self.candidates[name]["algo"] if name in self.candidates else name

    def hyperparams_for(self, name: str, env: str) -> list[str]:
        """The ``--hyperparams`` of a candidate on ``env``: its own, then its ``per_env`` ones (none for an algorithm)."""
        candidate = self.candidates.get(name, {})
        return [*candidate.get("hyperparams", []), *candidate.get("per_env", {}).get(env, [])]

    def episodes_for(self, env: str, default: int) -> int:
        """Episodes per evaluation on ``env``: the env's own (``evaluation: episodes_on``), else the study's, else
        ``default``."""
        return self.episodes_on.get(env) or self.evaluation_episodes or default

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
        evaluation = data.get("evaluation", {})
        normalisation = data.get("normalisation", MINMAX)
        if normalisation != MINMAX:
            normalisation = {env: (float(low), float(high)) for env, (low, high) in normalisation.items()}
        candidates = dict(data.get("candidates", {}))
        ranges = data.get("ranges", normalisation if normalisation != MINMAX else {})
        study = cls(
            path=path,
            name=data["name"],
            question=" ".join(data.get("question", "").split()),
            algos=list(candidates) or list(data["algos"]),
            envs=list(data["envs"]),
            seeds=[int(seed) for seed in data["seeds"]],
            normalisation=normalisation,
            candidate=data.get("candidate"),
            rule=list(data.get("rule", [])),
            final_evaluations=int(data.get("final_evaluations", 3)),
            final=str(data.get("final", "evaluations")),
            published={
                agent: {env: float(score) for env, score in by_env.items()}
                for agent, by_env in data.get("published", {}).items()
            },
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
            settings=str(data.get("settings", "tuned")),
            device=data.get("device"),
            evaluation_every=int(evaluation["every"]) if "every" in evaluation else None,
            evaluation_episodes=int(evaluation["episodes"]) if "episodes" in evaluation else None,
            episodes_on={env: int(episodes) for env, episodes in evaluation.get("episodes_on", {}).items()},
        )
        if study.tables not in ("study", "benchmark"):
            raise ValueError(f"{path}: tables must be 'study' or 'benchmark', not {study.tables!r}")
        if study.rule and (study.candidate is not None or not study.candidates) and study.candidate not in study.algos:
            raise ValueError(f"{path}: the candidate {study.candidate!r} is not one of the algos {study.algos}")
        return study
