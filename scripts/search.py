"""
The search: which Off-On configuration, and which ``n_steps`` for the n-step DQN baseline, on seeds 0-4.

The candidates, the tasks and the criterion are fixed here, before any run of the search (and written to
``results/search/README.md`` with the outcome, losers included):

- DQN settings: the zoo's tuned entries, unchanged (``hyperparams/dqn.yml``); only the target options vary.
- Off-On candidates (``mc_mixing``, the delta1 and delta2 schedules) on CartPole-v1, MountainCar-v0, LunarLander-v3,
  Acrobot-v1 and the stochastic FrozenLake-v1 (slippery), where a Monte-Carlo lower bound can mislead.
- n-step DQN: ``n_steps`` in 3, 5, 10 on the four benchmark tasks, chosen per task by the mean AUC.
- Criterion for the one Off-On configuration used on every task: among the candidates whose mean final return is, on
  every task, no more than 2% of the task's score range below DQN's ("never below DQN", with room for the noise of
  5 seeds), the highest mean over the five tasks of the normalised AUC (fixed per-task ranges below).

Round 2 (added on 2026-11-24, before any of its runs, after the head-to-head on seeds 10-19 showed n-step DQN ahead of
round 1's choice and both below DQN's final return on Acrobot): the round-1 ``max_*`` candidates lost CartPole's final
return, and their bound was not a lower bound there, since a time-limit cut's return was bootstrapped from the target
network. Candidates: ``max_drop``, the bound wherever an observed return is known, truncated episodes' returns left
unknown (``mc_truncation="drop"``); ``max_drop_nstep10``, the same on the 10-step TD targets of n-step DQN. Criterion:
a candidate earns a test on fresh seeds if, on seeds 0-4, (a) its mean final return is within round 1's bar of DQN's
on all five tasks, (b) within the same bar of ``nstep10``'s on the four benchmark tasks, and (c) its mean normalised
AUC over the four benchmark tasks is above ``nstep10``'s. Round 1's winner stays as it was.

Round 3 (stated on 2026-11-25 before any of its runs): the lambda-return mode (``mc_mixing="lambda"``,
``--algo offon_lambda``), delta1 read as lambda and delta2 as the trace-cut weight. Six candidates on the five tasks and
seeds 0-4 (150 runs): lambda 0.8, 0.9 or 0.95 with Watkins's cuts (delta2 = 1); lambda 0.9 with Peng's (delta2 = 0);
lambda 0.9 with delta2 rising linearly from 0 (Peng) to 1 (Watkins) over the task's exploration period, so that it
reaches Watkins when epsilon reaches its final value (a ramp: the schedules are linear, not steps); and the paper's
delta1 schedule read as lambda, 0.99 -> 0.01 over training, with Watkins's cuts. Criterion: (a) the mean final return
within round 1's bar of DQN's on all five tasks; (b) among those, the highest mean normalised AUC over the four
benchmark tasks is the choice; (c) the choice is said to beat n-step DQN on the tuning seeds only if that mean is
above ``nstep10``'s 0.820. The choice goes to the head-to-head on seeds 20-29 whether or not (c) holds, and (c) is
reported with it; if no candidate passes (a), none goes, and a further round is stated before its runs.

Round 4 (stated on 2026-11-25 after round 3 chose none and before any of its runs): three candidates, each
ending its training nearer one-step Q-learning than round 3's did, since round 3 lost FrozenLake with every lambda, and
CartPole (Watkins at lambda >= 0.9) or Acrobot (Peng) where lambda stayed high: the paper's delta1 schedule read as
lambda (0.99 -> 0.01 over training) with Peng's cuts; lambda 0.9 -> 0 over the first half of training with Peng's cuts,
one-step Q-learning after; lambda 0.7 throughout with Watkins's cuts. The criterion is round 3's, but FrozenLake-v1 is
judged on ten seeds (0-9), the candidates' and DQN's (DQN's seeds 5-9 made with the settings of its seeds 0-4): on five
seeds the standard error of DQN's own mean (0.031) exceeded the 0.02 bar. The bar stays 2% of the range below DQN's
mean; the other four tasks keep seeds 0-4.

Round 5 (stated on 2026-11-25 after round 4 chose none and before any of its runs): rounds 1-4's rule (every
task's five-seed mean within 2% of the range of DQN's) rejects DQN itself most of the time (``search_screen``'s
docstring), so it could not tell a candidate from DQN. Three settings from rounds 3 and 4, judged afresh on tuning seeds
30-34 that no run had used, DQN's reference on the same seeds: lambda 0.9 with Peng's cuts and the paper's schedule
(0.99 -> 0.01) with Peng's (the two highest mean normalised AUCs of rounds 3-4, 0.811 and 0.781), and lambda 0.8 with
Watkins's cuts (round 3's, below a bar on FrozenLake only). Criterion: (a) on no task of the five is the candidate
shown below DQN, i.e. the 95% bootstrap interval of the difference of the mean final returns does not lie wholly below
minus 2% of the range; (b) among those, the highest mean normalised AUC over the four benchmark tasks on seeds 30-34
is the choice; (c) reported: whether it is above ``nstep10``'s 0.820 (seeds 0-4) and above DQN's on seeds 30-34. The
choice goes to the head-to-head on seeds 20-29 as ``offon_lambda_choice``; if every candidate is shown below DQN
somewhere, none goes.

Runs that the earlier grids already made with the same settings and seeds (the tuned set: DQN, Off-On DQN and DQN with
MC on the four benchmark tasks) are read from there, not redone. New runs go to
``results/raw/search/<candidate>/tuned/<algo>/<env>_<seed>/`` through ``scripts/benchmark.py``'s own functions, so they
resume as the benchmark does.

Usage::

    python scripts/search.py run --workers 2                 # every missing run of the search
    python scripts/search.py run --candidates max_always --envs FrozenLake-v1
    python scripts/search.py report                          # results/search/summary.md from the finished runs
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchmark
import search_screen
from search_candidates import (
    BENCHMARK_ENVS,
    BY_NAME,
    OFFON_CANDIDATES,
    OFFON_ENVS,
    ROUND2_CANDIDATES,
    ROUND2_REFERENCE,
    ROUND3_CANDIDATES,
    ROUND4_CANDIDATES,
    ROUND4_SEEDS,
    ROUND5_CANDIDATES,
    ROUND5_REFERENCE,
    STOCHASTIC_ENV,
    TUNING_SEEDS,
    Candidate,
)

SEARCH_ROOT = Path("results/raw/search")
TUNED_ROOT = Path("results/raw/tuned")
# FrozenLake's return is 0 or 1: 50 episodes per evaluation, not 10, to see a success rate
EVAL_EPISODES = {STOCHASTIC_ENV: 50}
# Fixed score ranges for the normalisation (stated before the search): about a random policy's score to a solved one's
SCORE_RANGES = {
    "CartPole-v1": (0.0, 500.0),
    "MountainCar-v0": (-200.0, -100.0),
    "LunarLander-v3": (-250.0, 250.0),
    "Acrobot-v1": (-500.0, -60.0),
    "FrozenLake-v1": (0.0, 1.0),
}
# "Never below DQN": a mean final return at most this share of the task's range below DQN's
TOLERANCE = 0.02
# The highest return an episode can have, where the task bounds it: CartPole's 500-step limit at +1 a step, FrozenLake's
# one reward of 1. A candidate whose mean final return stays below a bar even if every missing seed ended there cannot
# reach that bar (its seeds still to come cannot change the choice, so they may run after the others')
SCORE_CEILINGS = {"CartPole-v1": 500.0, "FrozenLake-v1": 1.0}


def candidate_root(candidate: Candidate, env: str, search_root: Path = SEARCH_ROOT) -> Path:
    """Where the candidate's runs on ``env`` live: the tuned grid's, or the search's own folder."""
    if candidate.reuse_tuned and env in BENCHMARK_ENVS:
        return TUNED_ROOT.parent
    return search_root / candidate.name


def specs_of(
    candidate: Candidate, envs: list[str], seeds: list[int], device: str, search_root: Path
) -> list[tuple[dict, Path]]:
    """The benchmark specs of a candidate's runs, each with its results root."""
    pairs = []
    for env in envs:
        # One "a-a" range per seed: benchmark.py reads a lone number as a count of seeds
        argv = ["--set", "tuned", "--algos", candidate.algo, "--envs", env, "--seeds", *(f"{seed}-{seed}" for seed in seeds)]
        argv += ["--eval-episodes", str(EVAL_EPISODES.get(env, 10)), "--device", device]
        overrides = [*candidate.hyperparams, *candidate.per_env.get(env, [])]
        if overrides:
            argv += ["--hyperparams", *overrides]
        root = candidate_root(candidate, env, search_root)
        for spec in benchmark.build_specs(benchmark.parse_args(argv)):
            if candidate.run_name:
                spec["run_name"] = candidate.run_name  # into the folder of the runs made under the former name
            pairs.append((spec, root))
    return pairs


def run(args: argparse.Namespace) -> int:
    pairs = []
    for name in args.candidates:
        candidate = BY_NAME[name]
        for env in (env for env in candidate.envs if env in args.envs):
            seeds = args.seeds if args.seeds is not None else candidate.seeds_on(env)
            pairs += specs_of(candidate, [env], seeds, args.device, args.search_root)
    todo, conflicts = [], []
    for spec, root in pairs:
        status = benchmark.run_status(benchmark.run_dir(root, spec), spec)
        if status == "conflict":
            conflicts.append(benchmark.run_dir(root, spec))
        elif status == "todo":
            todo.append((spec, root))
    if conflicts:
        print("Finished runs with other settings (not redone):\n  " + "\n  ".join(map(str, conflicts)), file=sys.stderr)
        return 2
    print(f"{len(pairs)} runs in the search, {len(pairs) - len(todo)} finished, {len(todo)} to run on {args.workers} workers")
    if args.dry_run:
        for spec, root in todo:
            print(benchmark.run_dir(root, spec), " ".join(spec["hyperparams"]))
        return 0
    # Every spec is its own dict: the result's spec identifies its root
    roots = {id(spec): root for spec, root in todo}
    ordered = benchmark.run_order([spec for spec, _ in todo])
    failures = 0
    for result in benchmark.run_local(ordered, args.workers):
        spec = next(spec for spec in ordered if spec is result["spec"])
        ok, message = benchmark.store(result, roots[id(spec)])
        failures += not ok
        print(message, flush=True)
    return 1 if failures else 0


# ----------------------------------------------------------------------------------------------------------------------
# Report
# ----------------------------------------------------------------------------------------------------------------------
def run_scores(folder: Path, last: int = 3) -> tuple[float, float] | None:
    """Final return (mean of the last ``last`` evaluations) and AUC (mean evaluation return over training) of a run."""
    evaluations = benchmark.read_evaluations(folder)
    if evaluations is None or not (folder / benchmark.DONE).is_file():
        return None
    steps, returns = evaluations["timesteps"].astype(float), evaluations["results"].mean(axis=1)
    auc = np.trapezoid(returns, steps) / (steps[-1] - steps[0]) if len(steps) > 1 else returns[0]
    return float(returns[-last:].mean()), float(auc)


def collect(candidate: Candidate, env: str, search_root: Path = SEARCH_ROOT, seeds: list[int] = TUNING_SEEDS) -> np.ndarray:
    """(seeds, 2): final return and AUC of each finished run of ``seeds`` (fewer rows while runs are missing)."""
    rows = []
    for seed in seeds:
        folder = candidate_root(candidate, env, search_root) / "tuned" / candidate.folder_name / f"{env}_{seed}"
        scores = run_scores(folder)
        if scores is not None:
            rows.append(scores)
    return np.array(rows).reshape(-1, 2)


def normalise(env: str, value: np.ndarray | float) -> np.ndarray | float:
    low, high = SCORE_RANGES[env]
    return (value - low) / (high - low)


def bar(env: str, reference: float) -> float:
    """The lowest mean final return on ``env`` still within ``TOLERANCE`` of the task's range of ``reference``'s."""
    low, high = SCORE_RANGES[env]
    return reference - TOLERANCE * (high - low)


def within_bars(env: str, final: float, references: list[float]) -> bool:
    """Whether a mean final return on ``env`` is at most ``TOLERANCE`` of the task's range below every reference's."""
    return all(bool(final >= bar(env, reference)) for reference in references)


def candidate_row(
    scores: dict[str, np.ndarray],
    references: dict[str, list[float]],
    auc_envs: list[str] = OFFON_ENVS,
    n_seeds: dict[str, int] | None = None,
) -> tuple[list[str], float, bool, bool]:
    """
    A candidate's cells (final / AUC (seeds) per task of ``OFFON_ENVS``), its mean normalised AUC over ``auc_envs``,
    whether its mean final return is within the bar (``TOLERANCE`` of the range) of every reference final return of
    each finished task, and whether every task has all its seeds (``n_seeds`` per task, else the tuning seeds).
    """
    cells, normalised_auc, eligible, complete = [], [], True, True
    for env in OFFON_ENVS:
        values = scores[env]
        complete &= len(values) == seed_count(env, n_seeds)
        if not len(values):
            cells.append("—")
            continue
        final, auc = values.mean(axis=0)
        cells.append(f"{final:.3g} / {auc:.3g} ({len(values)})")
        eligible &= within_bars(env, final, references[env])
        if env in auc_envs:
            normalised_auc.append(normalise(env, auc))
    return cells, float(np.mean(normalised_auc)) if normalised_auc else np.nan, eligible, complete


def seed_count(env: str, n_seeds: dict[str, int] | None) -> int:
    """How many seeds a task is judged on: ``n_seeds[env]`` where given, else the tuning seeds'."""
    return (n_seeds or {}).get(env, len(TUNING_SEEDS))


def mean_finals(scores: dict[str, np.ndarray], envs: list[str]) -> dict[str, float]:
    """Per task, the mean final return over the finished seeds (NaN where none finished)."""
    return {env: scores[env][:, 0].mean() if len(scores[env]) else np.nan for env in envs}


def cannot_reach_bar(
    scores: dict[str, np.ndarray], references: dict[str, list[float]], n_seeds: dict[str, int] | None = None
) -> list[str]:
    """
    The tasks of ``OFFON_ENVS`` on which a candidate's mean final return over its seeds (``n_seeds`` per task, else the
    tuning seeds) would stay below the bar of some reference even if every seed still missing ended at the task's
    ceiling (``SCORE_CEILINGS``; tasks without one are never listed while a seed is missing). A finished task is listed
    when its mean is below the bar; a task whose reference is not known yet (NaN) never is.
    """
    below = []
    for env in OFFON_ENVS:
        finals = scores[env][:, 0] if len(scores[env]) else np.zeros(0)
        missing = seed_count(env, n_seeds) - len(finals)
        if (missing and env not in SCORE_CEILINGS) or np.isnan(references[env]).any():
            continue
        best_mean = (finals.sum() + missing * SCORE_CEILINGS.get(env, 0.0)) / seed_count(env, n_seeds)
        if not within_bars(env, best_mean, references[env]):
            below.append(env)
    return below


def bar_verdict(eligible: bool, complete: bool) -> str:
    """
    Within the bars: "yes"/"no" once every seed finished, else "pending" ("below so far" when a task's mean over the
    finished seeds is below: a seed still to come can lift it, so that is not yet a "no").
    """
    return ("yes" if eligible else "no") if complete else ("pending" if eligible else "pending (below so far)")


def report(args: argparse.Namespace) -> int:
    scores = {name: {env: collect(BY_NAME[name], env, args.search_root) for env in BY_NAME[name].envs} for name in BY_NAME}
    lines = [
        "# The search: every candidate on its tuning seeds",
        "",
        "Generated by `python scripts/search.py report` from the finished runs. Final return: mean of the last 3 "
        "evaluations; AUC: mean evaluation return over training (trapezoid); both averaged over the finished seeds "
        "(the count is given). Normalised with the fixed ranges "
        + ", ".join(f"{env} {r}" for env, r in SCORE_RANGES.items())
        + ".",
        "",
        "## Off-On configurations",
        "",
        "| Candidate | Settings | "
        + " | ".join(f"{env} final / AUC (n)" for env in OFFON_ENVS)
        + " | Mean normalised AUC | Never below DQN |",
        "|---|---|" + "---|" * len(OFFON_ENVS) + "---|---|",
    ]
    dqn_final = mean_finals(scores["dqn"], OFFON_ENVS)
    ranking = []
    for name in OFFON_CANDIDATES:
        cells, mean_auc, eligible, complete = candidate_row(scores[name], {env: [dqn_final[env]] for env in OFFON_ENVS})
        settings = BY_NAME[name].description
        verdict = bar_verdict(eligible, complete)
        lines.append(f"| {name} | {settings} | " + " | ".join(cells) + f" | {mean_auc:.3f} | {verdict} |")
        if complete:
            ranking.append((eligible, mean_auc, name))
    lines += ["", "## n-step DQN", "", "| Task | " + " | ".join(f"n={n} final / AUC (n)" for n in (3, 5, 10)) + " | Chosen |"]
    lines.append("|---|---|---|---|---|")
    for env in BENCHMARK_ENVS:
        cells, best = [], None
        for n in (3, 5, 10):
            values = scores[f"nstep{n}"][env]
            if len(values):
                final, auc = values.mean(axis=0)
                cells.append(f"{final:.3g} / {auc:.3g} ({len(values)})")
                if len(values) == len(TUNING_SEEDS) and (best is None or auc > best[0]):
                    best = (auc, n)
            else:
                cells.append("—")
        complete = all(len(scores[f"nstep{n}"][env]) == len(TUNING_SEEDS) for n in (3, 5, 10))
        lines.append(f"| {env} | " + " | ".join(cells) + f" | {best[1] if complete and best else 'pending'} |")
    lines.append("")
    winners = sorted((auc, name) for eligible, auc, name in ranking if eligible)
    if len(ranking) == len(OFFON_CANDIDATES):
        lines.append(f"**Winner** (highest mean normalised AUC among the eligible): {winners[-1][1] if winners else 'none'}")
    else:
        lines.append(f"**Winner: pending** ({len(ranking)} of {len(OFFON_CANDIDATES)} Off-On candidates complete)")
    lines += round2_lines(scores, dqn_final)
    lines += round3_lines(scores, dqn_final)
    # Round 4 judges FrozenLake on more seeds, DQN's reference included
    round4_scores = {
        name: {env: collect(BY_NAME[name], env, args.search_root, ROUND4_SEEDS.get(env, TUNING_SEEDS)) for env in OFFON_ENVS}
        for name in ["dqn", *ROUND4_CANDIDATES]
    }
    round4_scores[ROUND2_REFERENCE] = scores[ROUND2_REFERENCE]
    dqn_round4 = mean_finals(round4_scores["dqn"], OFFON_ENVS)
    dqn_round4 |= {env: np.nan for env, seeds in ROUND4_SEEDS.items() if len(round4_scores["dqn"][env]) < len(seeds)}
    lines += round4_lines(round4_scores, dqn_round4)
    lines += round5_lines(args.search_root, reference_mean_auc(scores))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


def round2_lines(scores: dict[str, dict[str, np.ndarray]], dqn_final: dict[str, float]) -> list[str]:
    """The round-2 table and verdicts: each candidate against DQN's bar (five tasks) and nstep10's (the four)."""
    reference = scores[ROUND2_REFERENCE]
    reference_final = mean_finals(reference, BENCHMARK_ENVS)
    reference_auc = reference_mean_auc(scores)
    lines = [
        "",
        "## Round 2: observed-return lower bounds, against n-step DQN",
        "",
        f"Reference: {ROUND2_REFERENCE}, mean normalised AUC over the four benchmark tasks "
        + (f"{reference_auc:.3f}." if not np.isnan(reference_auc) else "pending."),
        "",
        "| Candidate | Settings | "
        + " | ".join(f"{env} final / AUC (n)" for env in OFFON_ENVS)
        + " | Mean normalised AUC (4 tasks) | Within the bar of DQN (5) and nstep10 (4) | Fresh-seed test |",
        "|---|---|" + "---|" * len(OFFON_ENVS) + "---|---|---|",
    ]
    references = {env: [dqn_final[env]] + ([reference_final[env]] if env in BENCHMARK_ENVS else []) for env in OFFON_ENVS}
    for name in ROUND2_CANDIDATES:
        cells, mean_auc, eligible, complete = candidate_row(scores[name], references, auc_envs=BENCHMARK_ENVS)
        beats_reference = bool(mean_auc > reference_auc)  # False while the reference is pending (NaN)
        within = bar_verdict(eligible, complete)
        verdict = ("yes" if eligible and beats_reference else "no") if complete else within
        settings = BY_NAME[name].description
        lines.append(f"| {name} | {settings} | " + " | ".join(cells) + f" | {mean_auc:.3f} | {within} | {verdict} |")
    return lines


def reference_mean_auc(scores: dict[str, dict[str, np.ndarray]]) -> float:
    """``nstep10``'s mean normalised AUC over the four benchmark tasks (NaN until every task has a finished run)."""
    reference = scores[ROUND2_REFERENCE]
    if not all(len(reference[env]) for env in BENCHMARK_ENVS):
        return np.nan
    return float(np.mean([normalise(env, reference[env][:, 1].mean()) for env in BENCHMARK_ENVS]))


def round3_lines(scores: dict[str, dict[str, np.ndarray]], dqn_final: dict[str, float]) -> list[str]:
    """The round-3 table (the lambda-return stage) and its choice (:func:`lambda_round_lines`)."""
    return lambda_round_lines(scores, dqn_final, ROUND3_CANDIDATES, "## Round 3: lambda-returns")


def round4_lines(scores: dict[str, dict[str, np.ndarray]], dqn_final: dict[str, float]) -> list[str]:
    """
    The round-4 table and its choice: round 3's criterion, with FrozenLake-v1 judged on the ten seeds of
    ``ROUND4_SEEDS``, the candidates' and DQN's (``scores`` and ``dqn_final`` hold those seeds there).
    """
    title = "## Round 4: lambda-returns that end nearer one-step Q-learning (FrozenLake-v1 on seeds 0-9)"
    n_seeds = {env: len(seeds) for env, seeds in ROUND4_SEEDS.items()}
    return lambda_round_lines(scores, dqn_final, ROUND4_CANDIDATES, title, n_seeds)


def round5_lines(search_root: Path, nstep_auc: float) -> list[str]:
    """
    Round 5: its candidates and DQN's reference on their own seeds (30-34), judged by the screen of
    ``search_screen`` (not shown below DQN on any task by the interval of the difference), then the highest mean
    normalised AUC over the four benchmark tasks.
    """
    names = [ROUND5_REFERENCE, *ROUND5_CANDIDATES]
    scores = {
        name: {env: collect(BY_NAME[name], env, search_root, BY_NAME[name].seeds_on(env)) for env in OFFON_ENVS}
        for name in names
    }
    seeds = sorted({seed for name in names for env in OFFON_ENVS for seed in BY_NAME[name].seeds_on(env)})
    title = f"## Round 5: the fastest lambda-returns on fresh tuning seeds {seeds[0]}-{seeds[-1]}, judged by a screen"
    table = search_screen.screen_lines(
        scores,
        ROUND5_CANDIDATES,
        ROUND5_REFERENCE,
        {name: BY_NAME[name].description for name in names},
        SCORE_RANGES,
        TOLERANCE,
        len(seeds),
        BENCHMARK_ENVS,
        nstep_auc,
    )
    return ["", title, "", *table]


def lambda_round_lines(
    scores: dict[str, dict[str, np.ndarray]],
    dqn_final: dict[str, float],
    names: list[str],
    title: str,
    n_seeds: dict[str, int] | None = None,
) -> list[str]:
    """
    A round of lambda-return candidates ``names`` and its choice: within round 1's bar of DQN's final return
    (``dqn_final``) on the five tasks, then the highest mean normalised AUC over the four benchmark tasks, compared with
    ``nstep10``'s. The choice is made once every candidate is complete (``n_seeds`` per task, else the tuning seeds) or
    cannot reach a bar whatever its missing seeds score (:func:`cannot_reach_bar`), and DQN's references are known.
    """
    reference_auc = reference_mean_auc(scores)
    lines = [
        "",
        title,
        "",
        f"Reference: {ROUND2_REFERENCE}, mean normalised AUC over the four benchmark tasks {reference_auc:.3f}.",
        "",
        "| Candidate | Settings | "
        + " | ".join(f"{env} final / AUC (n)" for env in OFFON_ENVS)
        + " | Mean normalised AUC (4 tasks) | Within the bar of DQN (5) | Above nstep10's AUC |",
        "|---|---|" + "---|" * len(OFFON_ENVS) + "---|---|---|",
    ]
    ranking = []
    references = {env: [dqn_final[env]] for env in OFFON_ENVS}
    for name in names:
        cells, mean_auc, eligible, complete = candidate_row(scores[name], references, BENCHMARK_ENVS, n_seeds)
        out_of_reach = [] if complete else cannot_reach_bar(scores[name], references, n_seeds)
        above = ("yes" if mean_auc > reference_auc else "no") if complete else "pending"
        within = f"no: cannot reach it on {', '.join(out_of_reach)}" if out_of_reach else bar_verdict(eligible, complete)
        settings = BY_NAME[name].description
        lines.append(f"| {name} | {settings} | " + " | ".join(cells) + f" | {mean_auc:.3f} | {within} | {above} |")
        if complete or out_of_reach:
            ranking.append((eligible and complete, mean_auc, name))
    lines.append("")
    unknown = [env for env in OFFON_ENVS if np.isnan(dqn_final[env])]
    if unknown:
        lines.append(f"**Choice: pending** (DQN's reference not finished on {', '.join(unknown)})")
        return lines
    if len(ranking) < len(names):
        lines.append(f"**Choice: pending** ({len(ranking)} of {len(names)} candidates decided)")
        return lines
    eligible_ranked = sorted((auc, name) for eligible, auc, name in ranking if eligible)
    if not eligible_ranked:
        lines.append("**Choice: none** (no candidate within the bar of DQN on all five tasks)")
        return lines
    auc, name = eligible_ranked[-1]
    verdict = "above" if auc > reference_auc else "not above"
    lines.append(f"**Choice** (the highest mean normalised AUC within the bar): {name}, {auc:.3f}, {verdict} nstep10's")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run_parser = commands.add_parser("run", help="train the missing runs of the search")
    run_parser.add_argument("--candidates", nargs="+", default=list(BY_NAME), choices=list(BY_NAME))
    run_parser.add_argument("--envs", nargs="+", default=OFFON_ENVS)
    run_parser.add_argument(
        "--seeds", nargs="+", type=int, default=None, help="these seeds on every task (default: each candidate's own)"
    )
    run_parser.add_argument("--workers", type=int, default=2)
    run_parser.add_argument("--device", default="cpu")
    run_parser.add_argument("--search-root", type=Path, default=SEARCH_ROOT, help="where new runs go")
    run_parser.add_argument("--dry-run", action="store_true")
    report_parser = commands.add_parser("report", help="write the summary of the finished runs")
    report_parser.add_argument("--out", default="results/search/summary.md")
    report_parser.add_argument("--search-root", type=Path, default=SEARCH_ROOT, help="where the search's own runs are")
    args = parser.parse_args(argv)
    return run(args) if args.command == "run" else report(args)


if __name__ == "__main__":
    sys.exit(main())
