"""
``scripts/benchmark.py`` and ``scripts/plot.py`` end to end, on a tiny grid (2 algorithms x 1 env x 2 seeds x 300 steps).

The runner is run as a command, with the local pool and with a local Ray instance; it is then resumed after one run's
output is deleted, and ``plot.py`` draws every figure and table from the result (with a one-seed grid of the two
Section 4.4 tasks added, for their figures). Each training run costs ~12 s of CPU, mostly the interpreter's imports.
"""

import argparse
import importlib.metadata
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"
ALGOS = ["offon_dqn", "dqn"]
SEEDS = [0, 1]
ENV = "CartPole-v1"
SECTION_44 = ["CartPoleFallPenalty-v1", "MountainCarGoalBonus-v0"]
GRID = ["--set", "paper", "--algos", *ALGOS, "-n", "300", "--eval-freq", "100", "--eval-episodes", "2", "--workers", "2"]
TIMEOUT = 900


def benchmark(root: Path, *arguments: str) -> subprocess.CompletedProcess:
    command = [sys.executable, str(SCRIPTS / "benchmark.py"), *GRID, "--root", str(root), *arguments]
    return subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT)


def check(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-5000:]
    return result.stdout


def run_folders(root: Path) -> list[Path]:
    return [root / "paper" / algo / f"{ENV}_{seed}" for algo in ALGOS for seed in SEEDS]


def train_commands(dry_run_output: str) -> list[str]:
    """The training command lines that a ``--dry-run`` prints, one per planned run."""
    return [line for line in dry_run_output.splitlines() if "sb3_offon.train" in line]


def evaluations(folder: Path) -> dict[str, np.ndarray]:
    with np.load(folder / "evaluations.npz") as data:
        return {key: data[key] for key in data.files}


@pytest.fixture(scope="module")
def local_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("local") / "raw"
    output = check(benchmark(root, "--envs", ENV, "--seeds", "2"))
    assert "4 to run" in output
    return root


def test_dry_run_of_the_tuned_set(tmp_path: Path):
    output = check(benchmark(tmp_path, "--set", "tuned", "--dry-run", "--seeds", "3"))
    commands = train_commands(output)
    # 2 algos x the tuned set's 4 envs x 3 seeds; tuned is sb3_offon.train's default file: no -conf
    assert len(commands) == 24
    assert all("-conf" not in line and "--num-threads 1" in line for line in commands)
    assert not (tmp_path / "tuned").exists()
    # Seed by seed: an interrupted grid holds whole seeds
    seeds = [int(line.split("--seed ")[1].split()[0]) for line in commands]
    assert seeds == sorted(seeds)


def test_the_grid_says_which_seeds_it_runs(tmp_path: Path):
    """A lone number is a count (``--seeds 20``: seeds 0-19), so the first line names the seeds, not only their number."""
    module = load_script("benchmark")
    assert module.seeds_text(module.parse_seeds(["20"])) == "0-19"
    assert module.seeds_text(module.parse_seeds(["20-20"])) == "20"
    assert module.seeds_text(module.parse_seeds(["29", "20", "23-28"])) == "20, 23-29"
    output = check(benchmark(tmp_path, "--set", "tuned", "--envs", "CartPole-v1", "--seeds", "20", "23-24", "--dry-run"))
    assert output.splitlines()[0].startswith("6 runs (2 algos x 1 envs x 3 seeds (20, 23-24), 'tuned' set)"), output


def test_a_grid_named_apart_from_its_set(tmp_path: Path):
    output = check(
        benchmark(tmp_path, "--set", "tuned", "--name", "headtohead", "--envs", "CartPole-v1", "--seeds", "10-11", "--dry-run")
    )
    targets = [line.split(" -> ")[1] for line in output.splitlines() if " -> " in line]
    assert sorted(targets) == sorted(
        str(tmp_path / "headtohead" / algo / f"CartPole-v1_{seed}") for algo in ALGOS for seed in (10, 11)
    )
    commands = train_commands(output)
    assert len(commands) == len(targets) == 2 * len(ALGOS)
    assert all("-conf" not in line for line in commands), "the tuned settings"


def test_mlp_runs_train_on_the_cpu_unless_told_otherwise(tmp_path: Path):
    module = load_script("benchmark")
    assert module.default_device("MlpPolicy") == "cpu"
    assert module.default_device("CnnPolicy") == "auto"
    for extra, device in [((), "cpu"), (("--device", "cuda"), "cuda")]:
        output = check(benchmark(tmp_path, "--dry-run", "--seeds", "1", *extra))
        commands = train_commands(output)
        assert commands, "the dry run lists its commands"
        assert all(f"--device {device}" in line for line in commands)


def test_threads_per_run(tmp_path: Path):
    for extra, threads in [((), "1"), (("--threads", "2"), "2")]:
        commands = train_commands(check(benchmark(tmp_path, "--dry-run", "--seeds", "1", *extra)))
        assert commands and all(f"--num-threads {threads}" in line for line in commands)
    module = load_script("benchmark")
    spec = module.build_specs(
        module.parse_args(["--set", "tuned", "--envs", "CartPole-v1", "--seeds", "1", "--threads", "2"])
    )[0]
    assert spec["threads"] == 2

    def threads_of(spec: dict) -> str:
        command = module.train_command(spec, "logs")
        return command[command.index("--num-threads") + 1]

    assert threads_of(spec) == "2"
    del spec["threads"]  # a run recorded before --threads existed ran on one thread
    assert threads_of(spec) == "1"


def load_script(name: str):
    spec = importlib.util.spec_from_file_location(f"{name}_script", SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_run_order_is_seed_by_seed_longest_first():
    module = load_script("benchmark")
    grid = [
        {"algo": algo, "env": env, "seed": seed, "n_timesteps": budget}
        for algo in ("a", "b")
        for env, budget in (("short", 100), ("long", 300))
        for seed in (1, 0)
    ]
    order = [(spec["seed"], spec["env"], spec["algo"]) for spec in module.run_order(grid)]
    assert order == [
        (0, "long", "a"),
        (0, "long", "b"),
        (0, "short", "a"),
        (0, "short", "b"),
        (1, "long", "a"),
        (1, "long", "b"),
        (1, "short", "a"),
        (1, "short", "b"),
    ]


def test_code_version_without_git_comes_from_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    # A copy of the working tree without .git (another machine's scratch copy): the commit is named by the caller
    module = load_script("benchmark")
    (tmp_path / "sb3_offon" / "hyperparams").mkdir(parents=True)
    monkeypatch.setattr(module, "hyperparams_dir", lambda: tmp_path / "sb3_offon" / "hyperparams")
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))
    monkeypatch.setenv("SB3_OFFON_COMMIT", "0123abc")
    assert module.code_version() == {"commit": "0123abc"}
    module._CODE_VERSION.clear()
    monkeypatch.delenv("SB3_OFFON_COMMIT")
    assert module.code_version() == {"commit": "unknown"}


def test_local_pool_writes_the_zoo_layout(local_root: Path):
    for folder in run_folders(local_root):
        done = json.loads((folder / "done.json").read_text())
        assert done["returncode"] == 0 and done["wall_time_s"] > 0
        # Where and with what the run ran: this checkout's commit, this interpreter's libraries
        assert len(done["code_version"]["commit"].removesuffix("-dirty")) == 40
        assert done["versions"]["python"] == ".".join(map(str, sys.version_info[:3]))
        assert done["versions"]["stable_baselines3"] == importlib.metadata.version("stable_baselines3")
        # The paper's epsilon schedule keeps its end step (1919) under the 300-step budget: the whole run
        assert done["spec"]["hyperparams"] == ["exploration_fraction:1"]
        data = evaluations(folder)
        np.testing.assert_array_equal(data["timesteps"], [100, 200, 300])
        assert data["results"].shape == (3, 2) and done["n_evaluations"] == 3
        assert (folder / "0.monitor.csv").is_file() and (folder / ENV / "config.yml").is_file()
        assert "-conf paper" in (folder / ENV / "command.txt").read_text()
        # Small files only: no model zips, no replay buffers
        assert not [path for path in folder.rglob("*") if path.suffix in (".zip", ".pkl")]


def test_resume_redoes_only_the_unfinished_run(local_root: Path):
    folders = run_folders(local_root)
    # A key the runner never writes marks each done.json: a rewritten one loses it. (Modification times would say the
    # same only where the filesystem's clock is finer than the time between the writes.)
    for folder in folders:
        record = json.loads((folder / "done.json").read_text())
        (folder / "done.json").write_text(json.dumps({**record, "test_marker": folder.name}))
    marked = {folder: (folder / "done.json").read_text() for folder in folders}
    before = evaluations(folders[1])
    # Everything finished: nothing runs
    assert "0 to run" in check(benchmark(local_root, "--envs", ENV, "--seeds", "2"))
    assert marked == {folder: (folder / "done.json").read_text() for folder in folders}
    # Other settings than the finished runs': refused, nothing touched
    refused = benchmark(local_root, "--envs", ENV, "--seeds", "2", "--eval-episodes", "3")
    assert refused.returncode == 2 and "--force" in refused.stderr
    # One run's output deleted (as a crash would leave it): that run only is wiped and redone
    (folders[1] / "evaluations.npz").unlink()
    (folders[1] / "stale.txt").write_text("left by a crashed run")
    assert "1 to run" in check(benchmark(local_root, "--envs", ENV, "--seeds", "2"))
    for folder in folders:
        rewritten = "test_marker" not in json.loads((folder / "done.json").read_text())
        assert rewritten == (folder == folders[1])
    assert not (folders[1] / "stale.txt").exists()
    # Same seed, same command: the same evaluations
    for key, values in before.items():
        np.testing.assert_array_equal(evaluations(folders[1])[key], values)


def test_ray_runs_the_same_task(local_root: Path, tmp_path: Path):
    pytest.importorskip("ray")
    root = tmp_path / "raw"
    output = check(benchmark(root, "--envs", ENV, "--seeds", "2", "--ray"))
    assert "on Ray (local, 2 CPUs)" in output
    for ray_folder, local_folder in zip(run_folders(root), run_folders(local_root), strict=True):
        assert json.loads((ray_folder / "done.json").read_text())["returncode"] == 0
        for key, values in evaluations(local_folder).items():
            np.testing.assert_array_equal(evaluations(ray_folder)[key], values)


def test_plot_writes_every_figure_and_table(local_root: Path, tmp_path: Path):
    # The Section 4.4 tasks, one seed, for Figures 13-16
    check(benchmark(local_root, "--envs", *SECTION_44, "--seeds", "1"))
    out = tmp_path / "figures"
    page = tmp_path / "benchmarks.md"
    page.write_text("# Title\n\n<!-- results:paper:start -->\nold tables\n<!-- results:paper:end -->\n\nAfter.\n")
    command = [sys.executable, str(SCRIPTS / "plot.py"), "--root", str(local_root), "--set", "paper", "--out", str(out)]
    check(subprocess.run([*command, "--page", str(page)], capture_output=True, text=True, timeout=TIMEOUT))
    expected = [f"curves_{env}.png" for env in [ENV, *SECTION_44]]
    expected += ["fall_penalty_average.png", "fall_penalty_best.png", "fall_penalty_worst.png", "goal_reaches.png"]
    expected += ["aggregate.png", "table.md"]
    for name in expected:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    table = (out / "table.md").read_text()
    rows = [line for line in table.splitlines() if line.startswith("| ") and "(≥" in line]
    for env in [ENV, *SECTION_44]:
        for label in ["Off-On DQN", "DQN"]:
            assert sum(f"| {env} (≥" in row and f"| {label} |" in row for row in rows) == 1, (env, label)
    assert "## Across environments (rliable)" in table and "P(improvement over DQN)" in table
    assert "## Section 4.4: CartPoleFallPenalty-v1" in table and "## Section 4.4: MountainCarGoalBonus-v0" in table
    # --page: the page's block holds the same tables, the text around it is kept
    text = page.read_text()
    assert text.startswith("# Title\n\n<!-- results:paper:start -->\n")
    assert text.endswith("<!-- results:paper:end -->\n\nAfter.\n")
    assert "old tables" not in text and "**Section 4.4: MountainCarGoalBonus-v0**" in text
    assert table_rows(text) == table_rows(table)


def table_rows(text: str) -> list[str]:
    """The table rows and the generated lines that say what the aggregate covers."""
    return [line for line in text.splitlines() if line.startswith(("|", "Envs: "))]


def page_with_blocks(*blocks: str) -> str:
    parts = ["# Project\n\nText before, with a [link](x.md).\n"]
    for name, content in zip(("tuned", "paper"), blocks, strict=False):
        block = f"<!-- results:{name}:start -->\n{content}\n<!-- results:{name}:end -->"
        parts.append(f"\n## {name}\n\n{block}\n\nText after {name}.\n")
    return "".join(parts)


def test_plot_page_block_is_replaced_and_nothing_else(tmp_path: Path):
    module = load_script("plot")
    page = tmp_path / "benchmarks.md"
    page.write_text(page_with_blocks("| old | tuned |\n\nmore old lines", "| paper | block |"))
    module.replace_page_block(page, "tuned", "| new | tuned |")
    expected = page_with_blocks("| new | tuned |\n", "| paper | block |")
    assert page.read_text() == expected
    # Again: the same file (the block's own blank line before the end marker does not pile up)
    module.replace_page_block(page, "tuned", "| new | tuned |")
    assert page.read_text() == expected


def test_plot_page_without_markers_is_an_error_naming_the_marker(tmp_path: Path):
    module = load_script("plot")
    page = tmp_path / "benchmarks.md"
    page.write_text("# Project\n\nNo markers.\n")
    with pytest.raises(SystemExit, match="<!-- results:tuned:start --> is not found"):
        module.replace_page_block(page, "tuned", "| new |")
    page.write_text("# Project\n\n<!-- results:tuned:start -->\nno end marker\n")
    with pytest.raises(SystemExit, match="<!-- results:tuned:end --> is not found"):
        module.replace_page_block(page, "tuned", "| new |")
    page.write_text(page_with_blocks("a", "b").replace("results:paper", "results:tuned"))
    with pytest.raises(SystemExit, match="<!-- results:tuned:start --> is found 2 times"):
        module.replace_page_block(page, "tuned", "| new |")
    assert "| new |" not in page.read_text()
    # The command checks the page before any work (--readme, the option's former name): nothing is written
    page.write_text("# Project\n")
    out = tmp_path / "out"
    with pytest.raises(SystemExit, match="<!-- results:paper:start -->"):
        module.main(["--root", str(tmp_path / "raw"), "--set", "paper", "--out", str(out), "--readme", str(page)])
    assert not out.exists() and page.read_text() == "# Project\n"


@pytest.mark.parametrize("hyperparams_set", ["paper", "tuned", "headtohead"])
def test_plot_page_tables_are_the_results_tables(hyperparams_set: str):
    # The documentation's results page shows the tables of results/<set>/table.md
    # (python scripts/plot.py ... --page docs/benchmarks.md)
    root = SCRIPTS.parent
    text = (root / "docs" / "benchmarks.md").read_text()
    start, end = f"<!-- results:{hyperparams_set}:start -->", f"<!-- results:{hyperparams_set}:end -->"
    assert start in text and end in text
    block = text.split(start)[1].split(end)[0]
    assert table_rows(block) == table_rows((root / "results" / hyperparams_set / "table.md").read_text())


def test_against_dqn_rows_from_hand_made_scores():
    module = load_script("plot")
    seeds = np.arange(8.0)

    def scores(final, auc, steps):
        return {"final": np.asarray(final, float), "auc": np.asarray(auc, float), "steps": np.asarray(steps, float)}

    by_algo = {
        "dqn": scores(100 + 100 * (seeds % 4), 10 + seeds, 1000 * (seeds + 1)),  # final mean 250; steps IQM 4500
        "offon_choice": scores(400 + seeds - 3.5, 50 + seeds, 500 * (seeds + 1)),  # final mean 400; steps IQM 2250
        "qrdqn": scores(250 + (seeds - 3.5), 9 + seeds, 1000 * (seeds + 1)),  # AUC 9-16 against 10-17: overlapping
        "dqn_nstep": scores(250 - 10 * seeds, -20 - seeds, 2000 * (seeds + 1)),  # AUC far below
    }
    env = "CartPole-v1"
    args = argparse.Namespace(reps=500)
    rows = {row.split(" | ")[1]: row for row in module.against_baseline(args, {env: by_algo}, {env: by_algo})[4:]}
    assert set(rows) == {"Off-On DQN (search's choice)", "QR-DQN", "n-step DQN"}
    choice = rows["Off-On DQN (search's choice)"].split(" | ")
    assert choice[2].startswith("+150.0 [") and choice[3] == "above, apart" and choice[4].startswith("0.50 [")
    low, high = (float(value) for value in choice[4].split("[")[1].rstrip("] |").split(", "))
    assert low <= 0.5 <= high and low < high
    assert rows["QR-DQN"].split(" | ")[2].startswith("+0.0 [") and rows["QR-DQN"].split(" | ")[3] == "overlapping"
    assert rows["n-step DQN"].split(" | ")[3] == "below, apart" and rows["n-step DQN"].split(" | ")[4].startswith("2.00 [")
    # Without DQN there is nothing to compare with; a single run has no interval
    assert module.against_baseline(args, {env: {"qrdqn": 0}}, {env: {"qrdqn": by_algo["qrdqn"]}}) == []
    single = {algo: scores(value["final"][:1], value["auc"][:1], value["steps"][:1]) for algo, value in by_algo.items()}
    rows = module.against_baseline(args, {env: single}, {env: single})[4:]
    assert rows[0].split(" | ")[2:] == ["+296.5 (one run)", "(one run)", "0.50 (one run) |"]


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


def test_aggregate_waits_for_an_env_until_every_variant_has_its_seeds():
    """An env with a variant's runs still to come stays out of the IQM, and the table says why."""
    module, stats = load_script("plot"), load_script("run_stats")

    def cell(algo: str, env: str, finals: list[float], seeds: list[int]) -> tuple[list, dict]:
        runs = [
            stats.Run(algo, env, seed, 100, np.array([100]), np.array([final]), None)
            for seed, final in zip(seeds, finals, strict=True)
        ]
        return runs, {"final": np.array(finals), "auc": np.array(finals)}

    def grid(qrdqn_seeds_on_b: list[int]) -> tuple[dict, dict]:
        cells = {
            ("A", "dqn"): cell("dqn", "A", [0.0, 1.0, 2.0], [0, 1, 2]),
            ("A", "qrdqn"): cell("qrdqn", "A", [3.0, 4.0, 5.0], [0, 1, 2]),
            ("B", "dqn"): cell("dqn", "B", [0.0, 0.0, 0.0], [0, 1, 2]),
        }
        if qrdqn_seeds_on_b:
            cells["B", "qrdqn"] = cell("qrdqn", "B", [10.0] * len(qrdqn_seeds_on_b), qrdqn_seeds_on_b)
        runs, scores = {}, {}
        for (env, algo), (algo_runs, algo_scores) in cells.items():
            runs.setdefault(env, {})[algo] = algo_runs
            scores.setdefault(env, {})[algo] = algo_scores
        return runs, scores

    for qrdqn_seeds_on_b, why in [([], "no runs of QR-DQN"), ([0, 2], "QR-DQN 2 of 3 seeds")]:
        result = stats.aggregates(*grid(qrdqn_seeds_on_b), reps=200)
        assert result["envs"] == ["A"] and result["left_out"] == {"B": why}
        # Every variant keeps all three seeds of env A, and QR-DQN's runs there are all above DQN's
        assert result["runs"] == {"dqn": 3, "qrdqn": 3} and result["poi"]["qrdqn"][0] == 1.0
        text = module.left_out_text(result["left_out"])
        assert text == f" (left out until every variant has the same seeds there: B, {why})"
    complete = stats.aggregates(*grid([0, 1, 2]), reps=200)
    assert complete["envs"] == ["A", "B"] and complete["left_out"] == {} and complete["runs"] == {"dqn": 3, "qrdqn": 3}


def test_bootstrap_intervals_are_the_same_at_every_redraw():
    module = load_script("run_stats")
    values = np.random.default_rng(0).normal(size=(10, 5))
    first = module.mean_ci(values, reps=500)
    np.random.seed(123)  # whatever ran before must not matter (rliable draws from NumPy's global RNG)
    second = module.mean_ci(values, reps=500)
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.all(first[1] < first[0]) and np.all(first[0] < first[2]), "a real interval around the mean"


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
    assert lines({first: scores(0.0, 0.3, n_seeds=4)})[-1].startswith("**Choice: pending** (5 of 6")
    row = next(line for line in lines({first: scores(0.0, 0.3, n_seeds=4)}) if line.startswith(f"| {first} |"))
    assert row.rstrip(" |").split(" | ")[-2:] == ["pending", "pending"]


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

    def verdict(name: str, table: list[str]) -> str:
        return next(line for line in table if line.startswith(f"| {name} |")).rstrip(" |").split(" | ")[-2]

    first, second = module.ROUND3_CANDIDATES[:2]
    # Three seeds summing to 0: (0 + 2 x 500) / 5 = 200 < 240, out; summing to 201: (201 + 1000) / 5 = 240.2, still open
    out = lines({first: scores([0.0, 0.0, 0.0], n_seeds=3, auc=0.9)})
    assert verdict(first, out) == "no: cannot reach it on CartPole-v1"
    assert out[-1].startswith("**Choice** (the highest") and f": {first}," not in out[-1]
    still_open = lines({first: scores([67.0, 67.0, 67.0], n_seeds=3, auc=0.9)})
    assert verdict(first, still_open) == "pending (below so far)" and still_open[-1].startswith("**Choice: pending** (5 of 6")
    # A task with no ceiling (MountainCar) missing seeds never decides early, however low its mean so far
    low_mountaincar = scores([250.0] * 5)
    low_mountaincar["MountainCar-v0"] = np.array([[-200.0, -200.0]] * 3)
    assert verdict(second, lines({second: low_mountaincar})) == "pending (below so far)"


def test_search_round3_cuts_ramp_over_each_tasks_exploration_period(tmp_path: Path):
    """Peng to Watkins: delta2 reaches 1 when epsilon reaches its final value, task by task (the zoo's fractions)."""
    module = load_script("search")
    candidate = module.BY_NAME["lambda90_peng_to_watkins"]
    for env in module.OFFON_ENVS:
        entry = yaml.safe_load((Path(__file__).parents[1] / "hyperparams" / "offon_lambda.yml").read_text())[env]
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

    def verdict(name: str, table: list[str]) -> str:
        return next(line for line in table if line.startswith(f"| {name} |")).rstrip(" |").split(" | ")[-2]

    first, second = module.ROUND4_CANDIDATES[:2]
    # Ten seeds averaging 0.485 pass (bar 0.48); averaging 0.475 do not
    passing = lines({first: scores([0.4, 0.57] * 5, auc=0.3)})
    assert verdict(first, passing) == "yes" and passing[-1].endswith(f": {first}, 0.300, above nstep10's")
    failing = lines({first: scores([0.4, 0.55] * 5, auc=0.3)})
    assert verdict(first, failing) == "no" and f": {first}," not in failing[-1]
    # Five FrozenLake seeds of ten: pending, however good; below the bar even at 1.0 on the other five: out
    assert verdict(second, lines({second: scores([0.9] * 5)})) == "pending"
    assert lines({second: scores([0.9] * 5)})[-1].startswith("**Choice: pending** (2 of 3 candidates decided)")
    # (0 x 5 + 1.0 x 5) / 10 = 0.5 can still reach 0.48; (0 x 6 + 1.0 x 4) / 10 = 0.4 cannot
    assert verdict(second, lines({second: scores([0.0] * 5)})) == "pending (below so far)"
    assert verdict(second, lines({second: scores([0.0] * 6)})) == "no: cannot reach it on FrozenLake-v1"
    # Until DQN's ten FrozenLake seeds are done, nothing is decided on that task, and no choice is made
    pending_reference = lines({second: scores([0.0] * 6)}, dqn=middle | {"FrozenLake-v1": np.nan})
    assert verdict(second, pending_reference) == "pending (below so far)"
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

    def verdict(name: str, lines: list[str]) -> str:
        return next(line for line in lines if line.startswith(f"| {name} |")).rstrip(" |").split(" | ")[-1]

    # As DQN: passes. 3% of the range below on CartPole with a 5% spread: not shown below (the interval reaches above
    # -2%). 30% below on LunarLander: shown below there. The choice is the fastest of those that pass.
    lines = table(
        {
            "same": scores(0.6),
            "noisy_lower": scores(0.9, {"CartPole-v1": -0.03}),
            "far_below": scores(0.95, {"LunarLander-v3": -0.3}),
        }
    )
    assert verdict("same", lines) == "yes" and verdict("noisy_lower", lines) == "yes"
    assert verdict("far_below", lines) == "no: shown below on LunarLander-v3"
    assert lines[-1] == (
        "**Choice** (the highest mean normalised AUC among those not shown below DQN): noisy_lower, 0.900, "
        "above nstep10's 0.820 (seeds 0-4), above DQN's 0.400 (same seeds)"
    )
    assert table({"far_below": scores(0.95, {"LunarLander-v3": -0.3})})[-1].startswith("**Choice: none**")
    # Four seeds of the reference, or of a candidate: nothing judged, no choice
    short = table({"same": scores(0.6)}, reference=scores(0.4, seeds=4))
    assert verdict("same", short) == "pending" and short[-1].startswith("**Choice: pending** (0 of 1")
    assert verdict("same", table({"same": scores(0.6, seeds=4)})) == "pending"
    # The bound itself: below only when the interval's upper end is under minus the tolerance
    assert screen.shown_below((-20.0, -30.0, -10.5), 10.0) and not screen.shown_below((-20.0, -30.0, -10.0), 10.0)
    assert not screen.shown_below((-20.0, np.nan, np.nan), 10.0)
    point, low, high = screen.difference_interval(np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 0.0]))
    assert point == 2.0 and 1.0 <= low < 2.0 < high <= 3.0


def test_search_report_chooses_in_round5_and_write_choice_writes_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
):
    """From hand-made runs on seeds 30-34: `search.py report` chooses the fastest candidate not shown below DQN in round
    5, and `write_choice.py` writes that candidate's settings from the summary."""
    search, write_choice = load_script("search"), load_script("write_choice")
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
    out = tmp_path / "offon_lambda_choice.yml"
    assert write_choice.main(["--summary", str(summary), "--out", str(out)]) == 0
    entries = yaml.safe_load(out.read_text())
    expected = {"mc_initial_prob": 0.9, "mc_final_prob": 0.9, "qlearning_initial_prob": 0.0, "qlearning_final_prob": 0.0}
    assert all({key: entry[key] for key in expected} == expected for entry in entries.values())
    assert "lambda90_peng_r5" in capsys.readouterr().out


def test_dqn_against_its_bar_is_the_table_of_the_search_readme():
    """The README's table of DQN's own runs against the point rule's bars is what the script prints from the runs."""
    root = Path(__file__).parents[1]
    printed = subprocess.run(
        [sys.executable, str(SCRIPTS / "dqn_against_its_bar.py")], cwd=root, capture_output=True, text=True, check=True
    ).stdout
    rows = [line for line in printed.splitlines() if line.startswith("| ")]
    assert len(rows) == 1 + len(load_script("search").BENCHMARK_ENVS)
    readme = (root / "results" / "search" / "README.md").read_text()
    for row in rows:
        assert row in readme, row


def test_write_choice_writes_the_chosen_rounds_candidate(tmp_path: Path, capsys: pytest.CaptureFixture):
    """offon_lambda_choice.yml: offon_lambda.yml's entries with the settings of the round that chose; none chose, none."""
    module = load_script("write_choice")
    choice_line = "**Choice** (the highest mean normalised AUC within the bar): lambda90_peng_half, 0.800, not above nstep10's"
    summary = (
        "# Searches\n\n## Off-On configurations\n\n**Winner** (highest mean normalised AUC among the eligible): max_paper\n\n"
        "## Round 3: lambda-returns\n\n| a | b |\n\n**Choice: none** (no candidate within the bar)\n\n"
        f"## Round 4: lambda-returns that end nearer one-step Q-learning\n\n| a | b |\n\n{choice_line}\n"
    )
    assert module.chosen_candidate(summary) == ("Round 4", "lambda90_peng_half")
    no_choice = summary.replace(choice_line, "**Choice: pending** (2 of 3 candidates decided)")
    assert module.chosen_candidate(no_choice) is None
    (tmp_path / "summary.md").write_text(summary)
    out = tmp_path / "offon_lambda_choice.yml"
    assert module.main(["--summary", str(tmp_path / "summary.md"), "--out", str(out)]) == 0
    lambda_entries = yaml.safe_load((Path(__file__).parents[1] / "hyperparams" / "offon_lambda.yml").read_text())
    choice_entries = yaml.safe_load(out.read_text())
    targets = {
        "mc_initial_prob": 0.9,
        "mc_final_prob": 0.0,
        "mc_fraction": 0.5,
        "qlearning_initial_prob": 0.0,
        "qlearning_final_prob": 0.0,
    }
    assert set(choice_entries) == set(lambda_entries)
    for env, entry in lambda_entries.items():
        assert choice_entries[env] == {**entry, **targets}, env
    assert "round 4 of the search" in out.read_text() and "`lambda90_peng_half`" in out.read_text()
    assert "tuning seeds 0-4 (FrozenLake-v1: 0-9)" in " ".join(out.read_text().replace("#", " ").split())
    out.unlink()
    # A later round's choice wins; round 5's header says its seeds and its criterion
    round5_line = (
        "**Choice** (the highest mean normalised AUC among those not shown below DQN): lambda90_peng_r5, 0.810, "
        "not above nstep10's 0.820 (seeds 0-4), above DQN's 0.500 (same seeds)"
    )
    (tmp_path / "summary.md").write_text(summary + f"\n## Round 5: on fresh tuning seeds\n\n| a | b |\n\n{round5_line}\n")
    assert module.main(["--summary", str(tmp_path / "summary.md"), "--out", str(out)]) == 0
    text = out.read_text()
    assert "round 5 of the search" in text and "tuning seeds 30-34" in text and "bootstrap interval" in text
    for env, entry in lambda_entries.items():
        assert yaml.safe_load(text)[env] == {
            **entry,
            **targets,
            "mc_initial_prob": 0.9,
            "mc_final_prob": 0.9,
            "mc_fraction": 1.0,
        }
    out.unlink()
    (tmp_path / "summary.md").write_text(no_choice)
    assert module.main(["--summary", str(tmp_path / "summary.md"), "--out", str(out)]) == 1 and not out.exists()
    assert "nothing written" in capsys.readouterr().err


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
