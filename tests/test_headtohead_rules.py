"""The head-to-heads' rules (scripts/headtohead_rule.py, headtohead2_rule.py) from hand-made scores and grids."""

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import load_script


def test_headtohead_rule_from_hand_made_scores():
    """Issue 13's step-6 rule: the search's bar on every task's final return, AUC apart above DQN's on three of four."""
    module = load_script("headtohead_rule")
    seeds = np.arange(10.0)
    envs = ["CartPole-v1", "MountainCar-v0", "LunarLander-v3", "Acrobot-v1"]
    # 2% of each task's range (CartPole 0-500, MountainCar -200 to -100, LunarLander -250 to 250, Acrobot -500 to -60)
    margin = {"CartPole-v1": 10.0, "MountainCar-v0": 2.0, "LunarLander-v3": 10.0, "Acrobot-v1": 8.8}

    def grid(final_below: dict[str, float], auc_gap: dict[str, float], n_seeds: int = 10) -> dict:
        """DQN's final mean 0 and AUC 0-9 per task; the choice's final that far below, its AUC that far above."""
        return {
            env: {
                "dqn": {"final": seeds[:n_seeds] - 4.5, "auc": seeds[:n_seeds]},
                "offon_choice": {"final": seeds[:n_seeds] - 4.5 - final_below[env], "auc": seeds[:n_seeds] + auc_gap[env]},
            }
            for env in envs
        }

    apart, overlapping = 20.0, 1.0
    three_apart = dict(zip(envs, [apart, apart, apart, overlapping], strict=True))
    exactly_at_the_bar = dict(margin)
    verdict, lines = module.judge(grid(exactly_at_the_bar, three_apart), reps=500)
    assert verdict == "holds", lines
    assert lines[-1].startswith("Final return at or above the bar on 4 of 4") and "apart on 3 " in lines[-1]
    assert lines[3].endswith("not apart above") and lines[0].endswith("-> above, apart")

    below = dict(exactly_at_the_bar, **{"Acrobot-v1": margin["Acrobot-v1"] + 0.1})
    verdict, lines = module.judge(grid(below, three_apart), reps=500)
    assert verdict == "does not hold" and "-> BELOW" in lines[3], lines
    two_apart = dict(three_apart, **{"CartPole-v1": overlapping})
    assert module.judge(grid(exactly_at_the_bar, two_apart), reps=500)[0] == "does not hold"
    # Nine seeds, or a task without the choice's runs: no decision yet, whatever the numbers say
    assert module.judge(grid(exactly_at_the_bar, three_apart, n_seeds=9), reps=500)[0] == "incomplete"
    partial = grid(exactly_at_the_bar, three_apart)
    del partial["LunarLander-v3"]["offon_choice"]
    verdict, lines = module.judge(partial, reps=500)
    assert verdict == "incomplete" and lines[2] == "LunarLander-v3: no runs of offon_choice yet"


def test_headtohead2_rule_from_hand_made_scores():
    """Issue 27's rule: final return not below DQN's by the interval anywhere, and the IQM of normalised AUC above n-step's."""
    module = load_script("headtohead2_rule")
    envs = ["CartPole-v1", "MountainCar-v0", "LunarLander-v3", "Acrobot-v1"]
    seeds = np.arange(20, 30)
    spread = np.arange(10.0) - 4.5  # mean 0 over the ten seeds

    def grid(final_shift: dict[str, float], auc: dict[str, float], steps: float = 50.0, n_seeds: int = 10) -> tuple:
        """Each algorithm's final return = spread (+ the choice's shift), AUC = its level + spread; DQN takes 100 steps."""
        runs, scores = {}, {}
        for env in envs:
            for algo in module.ALGOS:
                kept = 9 if (algo == "qrdqn" and env == "Acrobot-v1" and n_seeds == 9) else 10
                shift = final_shift[env] if algo == module.CHOICE else 0.0
                runs.setdefault(env, {})[algo] = [
                    module.run_stats.Run(algo, env, int(seed), 100, np.array([100]), np.array([0.0]), None)
                    for seed in seeds[:kept]
                ]
                scores.setdefault(env, {})[algo] = {
                    "final": spread[:kept] + shift,
                    "auc": spread[:kept] / 10 + auc[algo],
                    "steps": np.full(kept, steps if algo == module.CHOICE else 100.0),
                }
        return runs, scores

    level = {"dqn": 0.0, "qrdqn": 1.0, "dqn_nstep": 5.0, module.CHOICE: 10.0}
    even = dict.fromkeys(envs, 0.0)
    verdict, lines = module.judge(*grid(even, level), reps=300)
    assert verdict == "holds", lines
    assert (
        lines[0].startswith("CartPole-v1 (10 vs 10 seeds): final return minus DQN's +0.0 [")
        and "-> not below zero" in lines[0]
    )
    assert lines[-5].endswith("4 of 4 tasks (all needed)") and lines[-4].endswith("yes")
    assert lines[-3].endswith("met"), "AUC 10 against 5 with a spread of 0.9: the intervals are apart"
    assert lines[-2].endswith("missed (above on 0)") and lines[-1].endswith("met (4 of 4)")

    # Far enough below DQN on one task that the interval of the difference lies below zero: the rule fails
    verdict, lines = module.judge(*grid(dict(even, **{"Acrobot-v1": -20.0}), level), reps=300)
    assert verdict == "does not hold" and lines[3].split(" -> ")[1].startswith("BELOW zero"), lines
    # Above by the interval on two tasks: that target is met; steps at 0.8x DQN's miss theirs
    verdict, lines = module.judge(
        *grid(dict(even, **{"CartPole-v1": 20.0, "MountainCar-v0": 20.0}), level, steps=80.0), reps=300
    )
    assert verdict == "holds" and lines[-2].endswith("met (above on 2)") and lines[-1].endswith("missed (0 of 4)"), lines
    # Slower than n-step DQN across the tasks: the rule fails on its second part
    verdict, lines = module.judge(*grid(even, dict(level, **{module.CHOICE: 4.0})), reps=300)
    assert verdict == "does not hold" and lines[-4].endswith("no") and lines[-3].endswith("missed"), lines
    # QR-DQN's cell on one task with nine seeds: the aggregate waits, but part 2 can be bounded over whatever its last
    # run shows (it only widens Acrobot-v1's range), and the choice's AUC is far above n-step DQN's everywhere
    # (and so can the target of the intervals: far apart whatever that run shows)
    verdict, lines = module.judge(*grid(even, level, n_seeds=9), reps=300, apart_step=0.05)
    assert verdict == "holds" and "still to run: qrdqn" in lines[3] and "waits until" in lines[4], lines
    assert lines[-7].endswith("n-step DQN's: decided early (below)"), lines
    assert lines[-6].endswith("apart: met, decided early (below)"), lines
    assert lines[-3].startswith("Rule 2 before Acrobot-v1's last runs") and "cannot change" in lines[-1], lines
    assert lines[-2].startswith("Target of the intervals before Acrobot-v1's last runs"), lines
    # ... and when the choice is level with n-step DQN except a little above on that task, a last run that widens its
    # range far enough would make them level: no decision
    runs, scores = grid(even, dict(level, **{module.CHOICE: 5.0}), n_seeds=9)
    scores["Acrobot-v1"][module.CHOICE]["auc"] = scores["Acrobot-v1"][module.CHOICE]["auc"] + 0.5
    verdict, lines = module.judge(runs, scores, reps=300, apart_step=0.05)
    assert verdict == "incomplete" and lines[-2].startswith("Rule 2 before Acrobot-v1's last runs"), lines
    assert lines[-5].endswith("apart: waits"), "a near tie: undecided, as part 2"
    # Part 1 failed on a task whose DQN and choice cells are complete: decided before QR-DQN's last run
    below = dict(even, **{"Acrobot-v1": -20.0})
    verdict, lines = module.judge(*grid(below, level, n_seeds=9), reps=300, apart_step=0.05)
    assert verdict == "does not hold" and "BELOW zero" in lines[3] and "cannot change" in lines[-1], lines
    # ... but not while the choice's own cell on that task lacks a seed: its tenth run could move the interval
    runs, scores = grid(below, level)
    runs["Acrobot-v1"][module.CHOICE] = runs["Acrobot-v1"][module.CHOICE][:9]
    scores["Acrobot-v1"][module.CHOICE] = {key: values[:9] for key, values in scores["Acrobot-v1"][module.CHOICE].items()}
    verdict, lines = module.judge(runs, scores, reps=300)
    assert verdict == "incomplete" and "BELOW zero" in lines[3] and "still to run: offon_lambda_choice" in lines[3], lines
    # One run each has no interval: the interim line says so instead of calling it below zero, and the task is not
    # counted against the choice (the cell is incomplete anyway)
    runs, scores = grid(dict(even, **{"Acrobot-v1": 30.0}), level)
    for env in envs:
        runs[env] = {algo: value[:1] for algo, value in runs[env].items()}
        scores[env] = {algo: {key: values[:1] for key, values in value.items()} for algo, value in scores[env].items()}
    verdict, lines = module.judge(runs, scores, reps=300)
    assert verdict == "incomplete" and "+30.0 (one run) -> no interval yet;" in lines[3], lines
    assert lines[-5].endswith("4 of 4 tasks (all needed)"), lines


def hand_made_open_grid(module, rng: np.random.Generator, qrdqn_runs: int, choice_mean: float) -> tuple[dict, dict]:
    """Seeds 20-29 of the four algorithms on the four tasks, QR-DQN's LunarLander-v3 cell short of ``qrdqn_runs`` runs."""
    runs, scores = {}, {}
    for env in ["CartPole-v1", "MountainCar-v0", "LunarLander-v3", "Acrobot-v1"]:
        for algo in module.ALGOS:
            n_runs = qrdqn_runs if (algo == "qrdqn" and env == "LunarLander-v3") else 10
            runs.setdefault(env, {})[algo] = [
                module.run_stats.Run(algo, env, seed, 100, np.array([100]), np.array([0.0]), None)
                for seed in range(20, 20 + n_runs)
            ]
            auc = rng.normal(choice_mean if algo == module.CHOICE else 0.0, 1.0, n_runs)
            scores.setdefault(env, {})[algo] = {"final": auc, "auc": auc, "steps": np.ones(n_runs)}
    return runs, scores


def completed_grid(module, runs: dict, scores: dict, to_come: np.ndarray) -> tuple[dict, dict]:
    """``hand_made_open_grid``'s grid with QR-DQN's LunarLander-v3 cell completed to seeds 20-29 by ``to_come``."""
    completed_runs = {env: dict(by_algo) for env, by_algo in runs.items()}
    completed = {env: dict(by_algo) for env, by_algo in scores.items()}
    completed["LunarLander-v3"]["qrdqn"] = {
        key: np.concatenate([values, to_come]) for key, values in scores["LunarLander-v3"]["qrdqn"].items()
    }
    completed_runs["LunarLander-v3"]["qrdqn"] = [
        module.run_stats.Run("qrdqn", "LunarLander-v3", seed, 100, np.array([100]), np.array([0.0]), None)
        for seed in range(20, 30)
    ]
    return completed_runs, completed


def test_headtohead2_auc_gap_bounds_hold_whatever_the_missing_runs_show():
    """The bounds of part 2 read early contain the gap that any completion of the open task gives."""
    module = load_script("headtohead2_rule")
    rng = np.random.default_rng(0)
    runs, scores = hand_made_open_grid(module, rng, qrdqn_runs=3, choice_mean=1.0)
    assert module.open_task(scores) == "LunarLander-v3"
    low, high = module.auc_gap_bounds(runs, scores, "LunarLander-v3", step=0.01)
    assert low < high
    # The seven runs to come: inside the present range, far outside it, or anywhere between
    for scale in (0.1, 1.0, 10.0, 1e4):
        completed_runs, completed = completed_grid(module, runs, scores, rng.normal(0.0, scale, 7))
        aggregate = module.run_stats.aggregates(completed_runs, completed, reps=10)
        gap = aggregate["iqm_auc"][module.CHOICE][0] - aggregate["iqm_auc"][module.NSTEP][0]
        assert low <= gap <= high, (scale, low, gap, high)
    # The grid's extremes are reached to within the slack: the bounds are not vacuous
    assert high - low < 2.0
    # Missing runs of n-step DQN, or on two tasks: nothing to bound
    scores["CartPole-v1"]["qrdqn"] = {key: values[:9] for key, values in scores["CartPole-v1"]["qrdqn"].items()}
    assert module.open_task(scores) is None


def test_headtohead2_apart_margins_are_the_aggregates_own_and_their_bounds_hold():
    """
    The target of the intervals read early: ``apart_margins`` at (p, q) equals what ``run_stats.aggregates`` computes
    once runs that widen the open task's range that way are in (same resamples, same percentiles), and the bounds of
    ``auc_apart_bounds`` contain it whatever the missing runs show.
    """
    module = load_script("headtohead2_rule")
    rng = np.random.default_rng(1)
    runs, scores = hand_made_open_grid(module, rng, qrdqn_runs=4, choice_mean=0.5)
    present = np.concatenate([values["auc"] for values in scores["LunarLander-v3"].values()])
    low, high = present.min(), present.max()
    reps = 200
    bounds = module.auc_apart_bounds(runs, scores, "LunarLander-v3", reps, step=0.05)
    margins = []
    for p, q in [(0.0, 1.0), (0.2, 0.7), (0.0, 0.5), (0.5, 1.0), (0.45, 0.55)]:
        # Six runs to come: two of them set the widened range [low', high'], in which [low, high] sits at [p, q]
        span = (high - low) / (q - p)
        to_come = np.array([low - p * span, low - p * span + span, *rng.uniform(low, high, 4)])
        aggregate = module.run_stats.aggregates(*completed_grid(module, runs, scores, to_come), reps=reps)
        margin = aggregate["iqm_auc"][module.CHOICE][1] - aggregate["iqm_auc"][module.NSTEP][2]
        computed = module.apart_margins(
            *module.normalised_auc(runs, scores, "LunarLander-v3"), reps, np.array([p]), np.array([q])
        )
        assert np.isclose(computed[0], margin, rtol=0, atol=1e-12), (p, q, computed, margin)
        assert bounds[0] <= margin <= bounds[1], (p, q, bounds, margin)
        margins.append(margin)
    assert len(set(np.round(margins, 6))) == len(margins), "the places matter: a test that could not tell them apart"
    # NumPy's global RNG is seeded inside; what ran before does not matter
    np.random.seed(7)
    assert module.auc_apart_bounds(runs, scores, "LunarLander-v3", reps, step=0.05) == bounds


@pytest.mark.parametrize("rule, fresh", [("headtohead_rule", [10, 19]), ("headtohead2_rule", [20, 29])])
def test_headtohead_rules_count_only_their_fresh_seeds(tmp_path: Path, rule: str, fresh: list[int]):
    """Runs on other seeds (a tuning seed, the other head-to-head's) are not read by a head-to-head's rule."""
    module = load_script(rule)
    for seed in (4, 9, 10, 19, 20, 29, 30):
        folder = tmp_path / "grid" / "dqn" / f"CartPole-v1_{seed}"
        folder.mkdir(parents=True)
        spec = {"algo": "dqn", "env": "CartPole-v1", "seed": seed, "n_timesteps": 200}
        (folder / "done.json").write_text(json.dumps({"spec": spec, "returncode": 0, "n_evaluations": 2}))
        np.savez(folder / "evaluations.npz", timesteps=np.array([100, 200]), results=np.full((2, 5), float(seed)))
        (folder / "0.monitor.csv").write_text('#{"t_start": 0}\nr,l,t\n10.0,10,0.1\n')
    runs, scores = module.run_stats.scores_on_seeds(tmp_path / "grid", ("dqn",), module.FRESH_SEEDS)
    assert [run.seed for run in runs["CartPole-v1"]["dqn"]] == fresh
    np.testing.assert_array_equal(scores["CartPole-v1"]["dqn"]["final"], np.array(fresh, dtype=float))
