"""
The search's screen (its fifth round, on tuning seeds 30-34): a candidate passes a task unless its final return is *shown* to be more than the tolerance
below DQN's, that is unless the whole 95% bootstrap interval of the difference of the mean final returns (candidate
minus DQN, each side's seeds resampled apart, ``run_stats.two_sample_ci``) lies below minus the tolerance (2% of the
task's range, rounds 1-4's bar).

Why a screen and not rounds 1-4's point rule: that rule asked the mean over five seeds to be within 2% of the range of
DQN's mean over five other runs on every one of five tasks, and DQN itself does not pass it. DQN's own runs on seeds
10-14 and 15-19 (the first head-to-head, the same settings) end CartPole-v1 at 309.0 and 387.3 on average, both below
the bar of 392.9 set by its seeds 0-4; drawing five of its fifteen runs at random passes all four benchmark tasks' bars
about one time in eight. A rule that rejects the reference most of the time cannot tell a candidate from it. The
screen rejects only what five seeds show to be worse; the strict test is the head-to-head on seeds 20-29, whose rule
(``results/headtohead2/README.md``) was written before any of its runs.
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import run_stats

# Bootstrap resamples of each interval (seeded in run_stats, so the same runs give the same verdict)
REPS = 10_000


def difference_interval(candidate: np.ndarray, reference: np.ndarray) -> tuple[float, float, float]:
    """Mean final return of ``candidate`` minus ``reference``'s, with its 95% percentile bootstrap interval."""
    return run_stats.two_sample_ci(np.asarray(candidate, float), np.asarray(reference, float), run_stats.mean_difference, REPS)


def shown_below(interval: tuple[float, float, float], tolerance: float) -> bool:
    """Whether the whole interval of the difference lies below ``-tolerance`` (a NaN bound shows nothing)."""
    return bool(interval[2] < -tolerance)


def normalised_auc(scores: dict[str, np.ndarray], ranges: dict[str, tuple[float, float]], envs: list[str]) -> float:
    """The mean over ``envs`` of the mean AUC (column 1 of ``scores[env]``) min-max normalised with ``ranges``."""
    values = []
    for env in envs:
        low, high = ranges[env]
        values.append((scores[env][:, 1].mean() - low) / (high - low))
    return float(np.mean(values))


def screen_lines(
    scores: dict[str, dict[str, np.ndarray]],
    names: list[str],
    reference: str,
    descriptions: dict[str, str],
    ranges: dict[str, tuple[float, float]],
    tolerance: float,
    n_seeds: int,
    auc_envs: list[str],
    nstep_auc: float,
) -> list[str]:
    """
    Round 5's table and choice. ``scores[name][env]``: (runs, 2) final return and AUC of each finished run on the
    round's seeds; ``reference``: DQN's name there. A candidate is judged once it and the reference have ``n_seeds``
    runs on every task: it passes unless it is :func:`shown_below` DQN on some task (``tolerance`` a share of
    ``ranges``). Among those that pass, the highest mean normalised AUC over ``auc_envs`` is the choice, compared with
    ``nstep_auc`` (n-step DQN's, ``nstep10`` on seeds 0-4) and with DQN's on the round's seeds.
    """
    envs = list(ranges)
    complete = {name: all(len(scores[name][env]) == n_seeds for env in envs) for name in [reference, *names]}
    lines = [
        "| Candidate | Settings | "
        + " | ".join(f"{env} final / AUC (n); difference to DQN [95% CI]" for env in envs)
        + " | Mean normalised AUC (4 tasks) | Not shown below DQN |",
        "|---|---|" + "---|" * len(envs) + "---|---|",
    ]
    ranking = []
    for name in [reference, *names]:
        cells, below = [], []
        for env in envs:
            values = scores[name][env]
            if not len(values):
                cells.append("—")
                continue
            final, auc = values.mean(axis=0)
            cell = f"{final:.3g} / {auc:.3g} ({len(values)})"
            if name != reference and complete[name] and complete[reference]:
                interval = difference_interval(values[:, 0], scores[reference][env][:, 0])
                cell += f"; {run_stats.interval_text(interval, '.3g')}"
                if shown_below(interval, tolerance * (ranges[env][1] - ranges[env][0])):
                    below.append(env)
            cells.append(cell)
        has_auc = all(len(scores[name][env]) for env in auc_envs)
        mean_auc = normalised_auc(scores[name], ranges, auc_envs) if has_auc else np.nan
        if name == reference:
            verdict = "(the reference)"
        elif not (complete[name] and complete[reference]):
            verdict = "pending"
        else:
            verdict = f"no: shown below on {', '.join(below)}" if below else "yes"
            ranking.append((not below, mean_auc, name))
        lines.append(f"| {name} | {descriptions[name]} | " + " | ".join(cells) + f" | {mean_auc:.3f} | {verdict} |")
    lines.append("")
    if len(ranking) < len(names):
        lines.append(f"**Choice: pending** ({len(ranking)} of {len(names)} candidates judged; DQN's reference and each")
        lines[-1] += f" candidate need {n_seeds} seeds on every task)"
        return lines
    passed = sorted((auc, name) for passes, auc, name in ranking if passes)
    if not passed:
        lines.append("**Choice: none** (every candidate shown below DQN on some task)")
        return lines
    auc, name = passed[-1]
    dqn_auc = normalised_auc(scores[reference], ranges, auc_envs)
    versus = f"{'above' if auc > nstep_auc else 'not above'} nstep10's {nstep_auc:.3f} (seeds 0-4)"
    versus += f", {'above' if auc > dqn_auc else 'not above'} DQN's {dqn_auc:.3f} (same seeds)"
    lines.append(f"**Choice** (the highest mean normalised AUC among those not shown below DQN): {name}, {auc:.3f}, {versus}")
    return lines
