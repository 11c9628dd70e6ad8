"""scripts/search.py: the search's rounds, bars and verdicts, from hand-made scores."""

from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import load_script


def cell(name: str, table: list[str], column: int = -2) -> str:
    """The cell ``column`` (from the right) of candidate ``name``'s row in a markdown table of the search."""
    return next(line for line in table if line.startswith(f"| {name} |")).rstrip(" |").split(" | ")[column]


def test_search_runs_the_seeds_it_is_given(tmp_path: Path):
    """``search.py run --seeds 3`` is seed 3 (benchmark.py alone would read a lone number as a count)."""
    module = load_script("search")
    candidate = module.BY_NAME["max_drop"]
    for seeds in ([3], [0], [1, 4]):
        specs = module.specs_of(candidate, ["CartPole-v1"], seeds, "cpu", tmp_path)
        assert [spec["seed"] for spec, _ in specs] == seeds and all(root == tmp_path / "max_drop" for _, root in specs)


def test_search_bar_is_two_percent_of_the_range_below_the_reference():
    """The bar of rounds 1-4 and of the first head-to-head's rule: 2% of each task's range below the reference."""
    module = load_script("search")
    assert module.bar("CartPole-v1", 400.0) == pytest.approx(390.0)  # range 0..500
    assert module.bar("LunarLander-v3", 100.0) == pytest.approx(90.0)  # range -250..250
    assert module.bar("MountainCar-v0", -120.0) == pytest.approx(-122.0)  # range -200..-100
    assert module.within_bars("CartPole-v1", 390.0, [400.0, 380.0])
    assert not module.within_bars("CartPole-v1", 389.9, [400.0, 380.0])


def test_search_round2_verdict_from_hand_made_scores():
    """Round 2 of the search: within the bar of DQN (five tasks) and nstep10 (four), and a mean normalised AUC above."""
    module = load_script("search")
    five = np.ones(5)
    tasks = module.OFFON_ENVS
    span = {env: module.SCORE_RANGES[env][1] - module.SCORE_RANGES[env][0] for env in tasks}
    # DQN and nstep10 both end at each range's midpoint; nstep10's AUC is a quarter into the range on every task
    middle = {env: sum(module.SCORE_RANGES[env]) / 2 for env in tasks}
    dqn_final = dict(middle)
    quarter = {env: module.SCORE_RANGES[env][0] + span[env] / 4 for env in tasks}
    reference = {env: np.column_stack([five * middle[env], five * quarter[env]]) for env in tasks}

    def verdict(final_below: float, auc_quarter: float, n_seeds: int = 5, env_below: str = "Acrobot-v1") -> list[str]:
        candidate = {
            env: np.column_stack(
                [
                    np.ones(n_seeds) * (middle[env] - (final_below * span[env] if env == env_below else 0.0)),
                    np.ones(n_seeds) * (module.SCORE_RANGES[env][0] + auc_quarter * span[env]),
                ]
            )
            for env in tasks
        }
        scores = {name: candidate for name in module.ROUND2_CANDIDATES} | {module.ROUND2_REFERENCE: reference}
        rows = [line for line in module.round2_lines(scores, dqn_final) if line.startswith("| max_drop")]
        assert len(rows) == len(module.ROUND2_CANDIDATES)
        return rows[0].rstrip(" |").split(" | ")[-3:]

    assert verdict(0.0, 0.30) == ["0.300", "yes", "yes"]
    # At the bar (2% of the range below both references) still within; past it, not
    assert verdict(0.02, 0.30)[1:] == ["yes", "yes"]
    assert verdict(0.021, 0.30)[1:] == ["no", "no"]
    # Within the bars, but an AUC not above nstep10's (0.25 normalised)
    assert verdict(0.0, 0.25)[1:] == ["yes", "no"]
    # FrozenLake is held to DQN's bar alone, and its AUC is not in the four-task mean
    assert verdict(0.021, 0.30, env_below="FrozenLake-v1")[1:] == ["no", "no"]
    # Four seeds: not decided, within the bars or below one (the fifth seed can still lift a mean over the bar)
    assert verdict(0.0, 0.30, n_seeds=4)[1:] == ["pending", "pending"]
    assert verdict(0.021, 0.30, n_seeds=4)[1:] == ["pending (below so far)", "pending (below so far)"]


def test_search_round3_choice_from_hand_made_scores():
    """Round 3: within DQN's bar on the five tasks, then the highest four-task AUC, compared with nstep10's."""
    module = load_script("search")
    tasks = module.OFFON_ENVS
    span = {env: module.SCORE_RANGES[env][1] - module.SCORE_RANGES[env][0] for env in tasks}
    middle = {env: sum(module.SCORE_RANGES[env]) / 2 for env in tasks}

    def scores(final_below: float, auc: float, n_seeds: int = 5, env_below: str = "Acrobot-v1") -> dict[str, np.ndarray]:
        """Every task ends at its midpoint (DQN's final return here) less ``final_below`` of the range on one task."""
        return {
            env: np.column_stack(
                [
                    np.full(n_seeds, middle[env] - (final_below * span[env] if env == env_below else 0.0)),
                    np.full(n_seeds, module.SCORE_RANGES[env][0] + auc * span[env]),
                ]
            )
            for env in tasks
        }

    def lines(candidates: dict[str, dict[str, np.ndarray]]) -> list[str]:
        everything = {name: scores(0.0, 0.1) for name in module.ROUND3_CANDIDATES} | candidates
        everything[module.ROUND2_REFERENCE] = scores(0.0, 0.25)  # nstep10's four-task mean: 0.25
        return module.round3_lines(everything, dict(middle))

    first, second = module.ROUND3_CANDIDATES[:2]
    # The higher AUC wins among those within the bar; a higher one below the bar on a task is passed over
    assert lines({first: scores(0.0, 0.30), second: scores(0.021, 0.40)})[-1].startswith("**Choice** (the highest")
    assert f": {first}, 0.300, above nstep10's" in lines({first: scores(0.0, 0.30), second: scores(0.021, 0.40)})[-1]
    assert f": {second}, 0.400, above" in lines({first: scores(0.0, 0.30), second: scores(0.02, 0.40)})[-1]
    # FrozenLake counts for the bar but not for the AUC; a choice below nstep10's AUC is said to be
    assert f": {second}, 0.200, not above" in lines({second: scores(0.0, 0.20, env_below="FrozenLake-v1")})[-1]
    passed_over = lines({second: scores(0.021, 0.20, env_below="FrozenLake-v1")})[-1]
    assert f": {second}," not in passed_over and passed_over.endswith(", 0.100, not above nstep10's")
    # Nobody within the bar: no choice; a candidate with four seeds: pending
    below = {name: scores(0.05, 0.3) for name in module.ROUND3_CANDIDATES}
    assert lines(below)[-1].startswith("**Choice: none**")
    four_seeds = lines({first: scores(0.0, 0.3, n_seeds=4)})
    assert four_seeds[-1].startswith("**Choice: pending** (5 of 6")
    assert [cell(first, four_seeds, -2), cell(first, four_seeds, -1)] == ["pending", "pending"]


def test_search_round3_decides_without_the_seeds_that_cannot_change_the_choice():
    """A candidate whose CartPole mean stays below DQN's bar even at 500 on every missing seed is out before its end."""
    module = load_script("search")
    tasks = module.OFFON_ENVS
    middle = {env: sum(module.SCORE_RANGES[env]) / 2 for env in tasks}  # DQN's final returns; CartPole's bar: 240

    def scores(cartpole_finals: list[float], n_seeds: int = 5, auc: float = 0.3) -> dict[str, np.ndarray]:
        rows = {env: np.column_stack([np.full(n_seeds, middle[env]), np.full(n_seeds, middle[env])]) for env in tasks}
        rows["CartPole-v1"] = np.column_stack([cartpole_finals, np.full(len(cartpole_finals), auc * 500)])
        return rows

    def lines(candidates: dict[str, dict[str, np.ndarray]]) -> list[str]:
        everything = {name: scores([250.0] * 5, auc=0.1) for name in module.ROUND3_CANDIDATES} | candidates
        everything[module.ROUND2_REFERENCE] = scores([250.0] * 5, auc=0.25)
        return module.round3_lines(everything, dict(middle))

    first, second = module.ROUND3_CANDIDATES[:2]
    # Three seeds summing to 0: (0 + 2 x 500) / 5 = 200 < 240, out; summing to 201: (201 + 1000) / 5 = 240.2, still open
    out = lines({first: scores([0.0, 0.0, 0.0], n_seeds=3, auc=0.9)})
    assert cell(first, out) == "no: cannot reach it on CartPole-v1"
    assert out[-1].startswith("**Choice** (the highest") and f": {first}," not in out[-1]
    still_open = lines({first: scores([67.0, 67.0, 67.0], n_seeds=3, auc=0.9)})
    assert cell(first, still_open) == "pending (below so far)" and still_open[-1].startswith("**Choice: pending** (5 of 6")
    # A task with no ceiling (MountainCar) missing seeds never decides early, however low its mean so far
    low_mountaincar = scores([250.0] * 5)
    low_mountaincar["MountainCar-v0"] = np.array([[-200.0, -200.0]] * 3)
    assert cell(second, lines({second: low_mountaincar})) == "pending (below so far)"


def test_search_round3_cuts_ramp_over_each_tasks_exploration_period(tmp_path: Path):
    """Peng to Watkins: delta2 reaches 1 when epsilon reaches its final value, task by task (the zoo's fractions)."""
    module = load_script("search")
    candidate = module.BY_NAME["lambda90_peng_to_watkins"]
    for env in module.OFFON_ENVS:
        entry = yaml.safe_load((Path(__file__).parents[1] / "hyperparams" / "offon_watkins.yml").read_text())[env]
        (spec, root), *_ = module.specs_of(candidate, [env], [0], "cpu", tmp_path)
        assert spec["algo"] == "offon_lambda" and root == tmp_path / candidate.name
        assert spec["hyperparams"][-3:] == [
            "qlearning_initial_prob:0.0",
            "qlearning_final_prob:1.0",
            f"qlearning_fraction:{float(entry['exploration_fraction'])}",
        ]


def test_search_round4_runs_frozenlake_on_ten_seeds(tmp_path: Path, capsys: pytest.CaptureFixture):
    """Round 4: seeds 0-9 on FrozenLake-v1, 0-4 elsewhere, unless ``--seeds`` says otherwise; its settings as stated."""
    module = load_script("search")
    args = ["run", "--candidates", "lambda90_peng_half", "--search-root", str(tmp_path), "--dry-run"]
    assert module.main(args) == 0
    listed = [line.split()[0] for line in capsys.readouterr().out.splitlines()[1:]]
    expected = [f"FrozenLake-v1_{seed}" for seed in range(10)] + [f"CartPole-v1_{seed}" for seed in range(5)]
    assert sorted(Path(folder).name for folder in listed if "FrozenLake" in folder or "CartPole" in folder) == sorted(expected)
    assert len(listed) == 4 * 5 + 10
    assert module.main([*args, "--seeds", "7"]) == 0
    assert [Path(line.split()[0]).name for line in capsys.readouterr().out.splitlines()[1:]] == [
        f"{env}_7" for env in module.OFFON_ENVS
    ]
    (spec, _), *_ = module.specs_of(module.BY_NAME["lambda90_peng_half"], ["Acrobot-v1"], [0], "cpu", tmp_path)
    assert spec["hyperparams"] == [
        "mc_initial_prob:0.9",
        "mc_final_prob:0.0",
        "mc_fraction:0.5",
        "qlearning_initial_prob:0.0",
        "qlearning_final_prob:0.0",
    ]
    assert module.BY_NAME["lambda_paper_peng"].hyperparams[:2] == ["mc_initial_prob:0.99", "mc_final_prob:0.01"]
    assert module.BY_NAME["lambda70_watkins"].hyperparams[-2:] == ["qlearning_initial_prob:1.0", "qlearning_final_prob:1.0"]


def test_search_round4_judges_frozenlake_on_ten_seeds():
    """Round 4: a FrozenLake mean over ten seeds against DQN's over ten; five seeds are not done, nor is DQN's reference."""
    module = load_script("search")
    tasks = module.OFFON_ENVS
    middle = {env: sum(module.SCORE_RANGES[env]) / 2 for env in tasks}  # DQN's final returns; FrozenLake's bar: 0.48

    def scores(frozenlake_finals: list[float], auc: float = 0.3) -> dict[str, np.ndarray]:
        rows = {env: np.column_stack([np.full(5, middle[env]), np.full(5, middle[env])]) for env in tasks}
        for env in module.BENCHMARK_ENVS:
            low, high = module.SCORE_RANGES[env]
            rows[env][:, 1] = low + auc * (high - low)
        rows["FrozenLake-v1"] = np.column_stack([frozenlake_finals, frozenlake_finals])
        return rows

    def lines(candidates: dict[str, dict[str, np.ndarray]], dqn: dict[str, float] = middle) -> list[str]:
        everything = {name: scores([0.5] * 10, auc=0.1) for name in module.ROUND4_CANDIDATES} | candidates
        everything[module.ROUND2_REFERENCE] = scores([0.5] * 5, auc=0.25)
        return module.round4_lines(everything, dict(dqn))

    first, second = module.ROUND4_CANDIDATES[:2]
    # Ten seeds averaging 0.485 pass (bar 0.48); averaging 0.475 do not
    passing = lines({first: scores([0.4, 0.57] * 5, auc=0.3)})
    assert cell(first, passing) == "yes" and passing[-1].endswith(f": {first}, 0.300, above nstep10's")
    failing = lines({first: scores([0.4, 0.55] * 5, auc=0.3)})
    assert cell(first, failing) == "no" and f": {first}," not in failing[-1]
    # Five FrozenLake seeds of ten: pending, however good; below the bar even at 1.0 on the other five: out
    assert cell(second, lines({second: scores([0.9] * 5)})) == "pending"
    assert lines({second: scores([0.9] * 5)})[-1].startswith("**Choice: pending** (2 of 3 candidates decided)")
    # (0 x 5 + 1.0 x 5) / 10 = 0.5 can still reach 0.48; (0 x 6 + 1.0 x 4) / 10 = 0.4 cannot
    assert cell(second, lines({second: scores([0.0] * 5)})) == "pending (below so far)"
    assert cell(second, lines({second: scores([0.0] * 6)})) == "no: cannot reach it on FrozenLake-v1"
    # Until DQN's ten FrozenLake seeds are done, nothing is decided on that task, and no choice is made
    pending_reference = lines({second: scores([0.0] * 6)}, dqn=middle | {"FrozenLake-v1": np.nan})
    assert cell(second, pending_reference) == "pending (below so far)"
    assert pending_reference[-1] == "**Choice: pending** (DQN's reference not finished on FrozenLake-v1)"


def test_search_round5_runs_on_fresh_tuning_seeds(tmp_path: Path, capsys: pytest.CaptureFixture):
    """Round 5: seeds 30-34 on every task, DQN's reference in a folder of its own; the settings of rounds 3-4's candidates."""
    module = load_script("search")
    for name in [module.ROUND5_REFERENCE, *module.ROUND5_CANDIDATES]:
        assert module.main(["run", "--candidates", name, "--search-root", str(tmp_path), "--dry-run"]) == 0
        listed = [Path(line.split()[0]) for line in capsys.readouterr().out.splitlines()[1:]]
        assert sorted(folder.name for folder in listed) == sorted(
            f"{env}_{seed}" for env in module.OFFON_ENVS for seed in range(30, 35)
        )
        # Under the search's root, not the tuned grid's: the grid keeps its own seeds
        assert all(folder.parents[2] == tmp_path / name for folder in listed)
    # Never the seeds of the first head-to-head (10-19) or those reserved for the second (20-29)
    used = {seed for candidate in module.BY_NAME.values() for env in candidate.envs for seed in candidate.seeds_on(env)}
    assert not used & set(range(10, 30))
    for name, earlier in [("lambda90_peng_r5", "lambda90_peng"), ("lambda_paper_peng_r5", "lambda_paper_peng")]:
        assert module.BY_NAME[name].hyperparams == module.BY_NAME[earlier].hyperparams
    assert module.BY_NAME["lambda80_watkins_r5"].hyperparams == module.BY_NAME["lambda80_watkins"].hyperparams
    assert module.BY_NAME[module.ROUND5_REFERENCE].algo == "dqn" and not module.BY_NAME[module.ROUND5_REFERENCE].hyperparams


def test_search_round5_screen_from_hand_made_scores():
    """Round 5's screen: out only where the interval of the difference lies wholly below the bar; then the highest AUC."""
    search = load_script("search")
    screen = search.search_screen
    ranges, tasks = search.SCORE_RANGES, search.OFFON_ENVS
    spread = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])  # mean 0

    def scores(auc: float, shift: dict[str, float] | None = None, seeds: int = 5) -> dict[str, np.ndarray]:
        """Finals: the middle of each range, 5% of the range apart from seed to seed, plus ``shift`` (a share of the range)."""
        rows = {}
        for env in tasks:
            low, high = ranges[env]
            finals = (low + high) / 2 + (spread * 0.05 + (shift or {}).get(env, 0.0)) * (high - low)
            rows[env] = np.column_stack([finals, np.full(5, low + auc * (high - low))])[:seeds]
        return rows

    def table(candidates: dict[str, dict[str, np.ndarray]], reference: dict[str, np.ndarray] | None = None) -> list[str]:
        everything = {"dqn_r5": reference if reference is not None else scores(0.4), **candidates}
        descriptions = {name: name for name in everything}
        return screen.screen_lines(
            everything, list(candidates), "dqn_r5", descriptions, ranges, 0.02, 5, search.BENCHMARK_ENVS, 0.82
        )

    # As DQN: passes. 3% of the range below on CartPole with a 5% spread: not shown below (the interval reaches above
    # -2%). 30% below on LunarLander: shown below there. The choice is the fastest of those that pass.
    lines = table(
        {
            "same": scores(0.6),
            "noisy_lower": scores(0.9, {"CartPole-v1": -0.03}),
            "far_below": scores(0.95, {"LunarLander-v3": -0.3}),
        }
    )
    assert cell("same", lines, -1) == "yes" and cell("noisy_lower", lines, -1) == "yes"
    assert cell("far_below", lines, -1) == "no: shown below on LunarLander-v3"
    assert lines[-1] == (
        "**Choice** (the highest mean normalised AUC among those not shown below DQN): noisy_lower, 0.900, "
        "above nstep10's 0.820 (seeds 0-4), above DQN's 0.400 (same seeds)"
    )
    assert table({"far_below": scores(0.95, {"LunarLander-v3": -0.3})})[-1].startswith("**Choice: none**")
    # Four seeds of the reference, or of a candidate: nothing judged, no choice
    short = table({"same": scores(0.6)}, reference=scores(0.4, seeds=4))
    assert cell("same", short, -1) == "pending" and short[-1].startswith("**Choice: pending** (0 of 1")
    assert cell("same", table({"same": scores(0.6, seeds=4)}), -1) == "pending"
    # The bound itself: below only when the interval's upper end is under minus the tolerance
    assert screen.shown_below((-20.0, -30.0, -10.5), 10.0) and not screen.shown_below((-20.0, -30.0, -10.0), 10.0)
    assert not screen.shown_below((-20.0, np.nan, np.nan), 10.0)
    point, low, high = screen.difference_interval(np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 0.0]))
    assert point == 2.0 and 1.0 <= low < 2.0 < high <= 3.0


def test_search_report_chooses_in_round5(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """From hand-made runs on seeds 30-34: `search.py report` chooses the fastest candidate not shown below DQN in round
    5."""
    search = load_script("search")
    monkeypatch.chdir(Path(__file__).parents[1])  # earlier rounds read the tuned grid's committed runs
    root = tmp_path / "search"

    def make_run(name: str, env: str, seed: int, shares: list[float]) -> None:
        """Four evaluations (one episode each) at these shares of the task's range, 1% of the range apart per seed."""
        low, high = search.SCORE_RANGES[env]
        folder = root / name / "tuned" / search.BY_NAME[name].algo / f"{env}_{seed}"
        folder.mkdir(parents=True)
        returns = low + (np.array(shares) + 0.01 * (seed - 32)) * (high - low)
        np.savez(folder / "evaluations.npz", timesteps=np.arange(4) * 1000, results=returns[:, None])
        (folder / "done.json").write_text("{}")

    slow, fast, fastest = [0.0, 0.5, 0.5, 0.5], [0.5, 0.5, 0.5, 0.5], [1.0, 0.5, 0.5, 0.5]
    for env in search.OFFON_ENVS:
        for seed in range(30, 35):
            make_run("dqn_r5", env, seed, slow)
            make_run("lambda80_watkins_r5", env, seed, slow)
            make_run("lambda90_peng_r5", env, seed, fast)
            # The fastest, but it ends LunarLander-v3 at the bottom of the range
            make_run("lambda_paper_peng_r5", env, seed, [1.0, 0.0, 0.0, 0.0] if env == "LunarLander-v3" else fastest)
    summary = tmp_path / "summary.md"
    assert search.main(["report", "--out", str(summary), "--search-root", str(root)]) == 0
    round5 = summary.read_text().split("## Round 5")[1]
    assert "| lambda_paper_peng_r5 |" in round5 and "no: shown below on LunarLander-v3 |" in round5
    assert "**Choice** (the highest mean normalised AUC among those not shown below DQN): lambda90_peng_r5, 0.500," in round5
