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
from types import ModuleType

import numpy as np
import pytest
from helpers import SCRIPTS, interrupt_after_checkpoint, load_script

from sb3_offon.train import main as train_main

ALGOS = ["offon_paper", "dqn"]
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
    grid_specs = load_script("grid_specs")
    assert grid_specs.seeds_text(grid_specs.parse_seeds(["20"])) == "0-19"
    assert grid_specs.seeds_text(grid_specs.parse_seeds(["20-20"])) == "20"
    assert grid_specs.seeds_text(grid_specs.parse_seeds(["29", "20", "23-28"])) == "20, 23-29"
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
    grid_specs = load_script("grid_specs")
    assert grid_specs.default_device("MlpPolicy") == "cpu"
    assert grid_specs.default_device("CnnPolicy") == "auto"
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


def test_the_runs_left_of_a_seed_go_in_the_grids_env_order():
    # The first env's first algorithms are finished: its last algorithm still runs first, as the grid orders envs
    module = load_script("benchmark")
    left = [{"algo": "c", "env": "first", "seed": 0, "n_timesteps": 100}]
    left += [{"algo": algo, "env": "second", "seed": 0, "n_timesteps": 100} for algo in ("a", "b", "c")]
    left = sorted(left, key=lambda spec: spec["algo"])  # the grid's own order: algo by algo
    order = [(spec["env"], spec["algo"]) for spec in module.run_order(left, ["first", "second"])]
    assert order == [("first", "c"), ("second", "a"), ("second", "b"), ("second", "c")]


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


def test_each_part_of_a_run_keeps_the_commit_it_started_from(tmp_path: Path):
    """A run records the commit its subprocess started from, not the one the driver reads when it stores the run (the
    checkout may have moved on during a long run); a resumed run, the commit of each part its checkpoint holds."""
    module = load_script("benchmark")
    folder = tmp_path / "checkpoints"
    assert module.record_start(folder, "aaa", 0) == ["aaa"]  # a fresh start
    assert module.record_start(folder, "bbb", 1) == ["aaa", "bbb"]  # resumed from the first part's checkpoint
    # Resumed again from the first part's checkpoint (the second left none intact): the second part's work is not in it
    assert module.record_start(folder, "ccc", 1) == ["aaa", "ccc"]
    # A run whose first part started before the file was kept
    assert module.record_start(tmp_path / "older", "ddd", 1) == [None, "ddd"]
    assert json.loads((folder / "commits.json").read_text()) == ["aaa", "ccc"]
    # What done.json records: the part's commit, the parts' only where there were several, the driver's as a fallback
    assert module.run_code_version({"code_version": {"commit": "aaa", "commits": ["aaa"]}}) == {"commit": "aaa"}
    resumed = {"code_version": {"commit": "ccc", "commits": ["aaa", "ccc"]}}
    assert module.run_code_version(resumed) == {"commit": "ccc", "commits": ["aaa", "ccc"]}
    module._CODE_VERSION["commit"] = "driver"
    assert module.run_code_version({"code_version": {"commit": None, "commits": [None]}}) == {"commit": "driver"}
    assert module.run_code_version({}) == {"commit": "driver"}  # a result from before the task read any


@pytest.mark.slow
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


@pytest.mark.slow
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


ONE_RUN = ["--envs", ENV, "--seeds", "1", "--algos", "dqn"]


def one_run(root: Path) -> tuple[ModuleType, dict, Path]:
    """The runner as a module, the spec of DQN's run on seed 0 under ``root``, and its checkpoint folder."""
    module = load_script("benchmark")
    (spec,) = module.build_specs(module.parse_args([*GRID, "--root", str(root), *ONE_RUN]))
    return module, spec, Path(spec["checkpoint_dir"])


def test_an_interrupted_run_resumes_from_its_checkpoint(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    root, arguments = tmp_path / "raw", ONE_RUN
    module, spec, folder = one_run(root)
    assert folder == (root / ".checkpoints" / "paper" / "dqn" / f"{ENV}_0").resolve() and spec["checkpoint_freq"] == 100
    # The run as the runner starts it, stopped (Ctrl-C) after its checkpoint of step 200
    module.start_checkpoints(folder, spec)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["sb3_offon.train", *module.train_command(spec, "logs")[2:]])
    with monkeypatch.context() as patch:
        interrupt_after_checkpoint(patch, 200)
        train_main()
    assert module.resume_point(spec) == [200]
    assert module.resume_point({**spec, "eval_episodes": 3}) == []  # made with other settings: not resumed
    # A damaged newest checkpoint: the run resumes from the one before, and says so
    model = folder / "200" / "model.zip"
    intact = model.read_bytes()
    model.write_bytes(intact[: len(intact) // 2])
    assert module.resume_point(spec) == [100]
    older = folder / "100" / "checkpoint.json"
    older_state = older.read_text()
    older.unlink()
    assert module.resume_point(spec) == []  # none complete: the run starts afresh
    older.write_text(older_state)
    model.write_bytes(intact)
    assert module.resume_point(spec) == [200]
    assert "(resumes at step 200)" in check(benchmark(root, *arguments, "--dry-run"))
    output = check(benchmark(root, *arguments))
    assert "(resumed at step 200)" in output
    run = root / "paper" / "dqn" / f"{ENV}_0"
    done = json.loads((run / "done.json").read_text())
    assert done["resumed_at"] == [200] and "--resume" in done["command"] and "checkpoint_dir" not in done["spec"]
    # Its first part started outside the runner, which kept no commit of it; the second's is this checkout's
    commit = done["code_version"]["commit"]
    assert done["code_version"]["commits"] == [None, commit] and len(commit.removesuffix("-dirty")) == 40
    np.testing.assert_array_equal(evaluations(run)["timesteps"], [100, 200, 300])
    assert not folder.exists() and not folder.with_name(f"{folder.name}.scratch").exists()


FAKE_RUN = """
import pathlib, sys
import numpy as np
folder = pathlib.Path("logs/dqn/CartPole-v1_1")
folder.mkdir(parents=True)
steps = [int(step) for step in sys.argv[1:]]
scores = np.ones((len(steps), 2))
np.savez(folder / "evaluations.npz", timesteps=np.array(steps), results=scores, ep_lengths=scores)
(folder / "0.monitor.csv").write_text("#\\nr,l,t\\n")
"""


def test_a_run_that_stops_short_with_return_code_0_keeps_its_checkpoints(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    root = tmp_path / "raw"
    module, spec, folder = one_run(root)
    for steps, whole_way in [(["100"], False), (["100", "200"], False), (["100", "200", "300"], True)]:
        # A stand-in for the training process: it exits with 0 after writing evaluations up to steps[-1] of 300 (as the
        # zoo does after a Ctrl-C)
        module.start_checkpoints(folder, spec)
        monkeypatch.setattr(module, "train_command", lambda spec, log_folder, steps=steps: ["-c", FAKE_RUN, *steps])
        result = module.run_one(spec)
        assert result["returncode"] == 0
        ok, message = module.store(result, module.run_dir(root, spec), {})
        assert ok == whole_way and folder.exists() != whole_way, steps
        if not whole_way:
            assert f"stopped after its evaluation at step {steps[-1]} of 300" in message
            assert (module.run_dir(root, spec) / "failed.json").is_file()
    assert module.run_status(module.run_dir(root, spec), spec) == "finished"


def test_a_run_its_stop_rule_ended_is_finished_and_drops_its_checkpoints(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    root = tmp_path / "raw"
    module, spec, folder = one_run(root)
    module.start_checkpoints(folder, spec)
    # The training process's stop rule ended it after its evaluation at 100 of 300 steps: it says so in stopped.json
    stopped = FAKE_RUN + '(folder / "stopped.json").write_text(\'{"num_timesteps": 150}\')\n'
    monkeypatch.setattr(module, "train_command", lambda spec, log_folder: ["-c", stopped, "100"])
    ok, message = module.store(module.run_one(spec), module.run_dir(root, spec), {})
    assert ok, message
    assert (module.run_dir(root, spec) / "stopped.json").is_file() and not folder.exists()
    assert module.run_status(module.run_dir(root, spec), spec) == "finished"


def test_a_run_another_runner_holds_is_left_to_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys):
    root = tmp_path / "raw"
    module, spec, _ = one_run(root)
    monkeypatch.setattr(module, "train_command", lambda spec, log_folder: ["-c", FAKE_RUN, "100", "200", "300"])
    other_runner = module.claim(root, spec)
    assert other_runner is not None and module.claim(root, spec) is None, "one holder at a time"
    assert module.main([*GRID, "--root", str(root), *ONE_RUN]) == 0
    output = capsys.readouterr()
    assert "taken by another runner, left to it" in output.out + output.err
    assert not module.run_dir(root, spec).exists(), "neither trained nor emptied nor stored by the second runner"
    module.release(other_runner)
    assert module.main([*GRID, "--root", str(root), *ONE_RUN]) == 0
    assert module.run_status(module.run_dir(root, spec), spec) == "finished"
    assert module.claim(root, spec) is None, "a finished run is not taken again"


@pytest.mark.slow
def test_ray_runs_the_same_task(local_root: Path, tmp_path: Path):
    pytest.importorskip("ray")
    root = tmp_path / "raw"
    output = check(benchmark(root, "--envs", ENV, "--seeds", "2", "--ray"))
    assert "on Ray (local, 2 CPUs)" in output
    for ray_folder, local_folder in zip(run_folders(root), run_folders(local_root), strict=True):
        assert json.loads((ray_folder / "done.json").read_text())["returncode"] == 0
        for key, values in evaluations(local_folder).items():
            np.testing.assert_array_equal(evaluations(ray_folder)[key], values)


@pytest.mark.slow
def test_plot_writes_every_figure_and_table(local_root: Path, tmp_path: Path):
    # The Section 4.4 tasks, one seed, for Figures 13-16
    check(benchmark(local_root, "--envs", *SECTION_44, "--seeds", "1"))
    out = tmp_path / "figures"
    command = [sys.executable, str(SCRIPTS / "plot.py"), "--root", str(local_root), "--set", "paper", "--out", str(out)]
    check(subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT))
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


def test_a_study_file_gives_the_grid(tmp_path: Path):
    """--study: the study's settings, algos, envs, seeds, evaluation and folder; --algos and --seeds narrow it; a
    renamed algorithm (run_names) keeps its runs' folder."""
    module = load_script("benchmark")
    study = tmp_path / "toy.yml"
    study.write_text(
        "name: toy\nsettings: tuned\nfolder: toy_runs\nalgos: [dqn, offon_paper]\nenvs: [CartPole-v1, Acrobot-v1]\n"
        "seeds: [40, 41]\nevaluation: {every: 500, episodes: 3}\nrun_names: {offon_paper: offon_dqn}\ndevice: cuda\n"
    )
    specs = module.build_specs(module.parse_args(["--study", str(study)]))
    assert {(spec["algo"], spec["env"], spec["seed"]) for spec in specs} == {
        (algo, env, seed) for algo in ("dqn", "offon_paper") for env in ("CartPole-v1", "Acrobot-v1") for seed in (40, 41)
    }
    assert all(spec["grid"] == "toy_runs" and spec["set"] == "tuned" for spec in specs)
    assert all(spec["eval_freq"] == 500 and spec["eval_episodes"] == 3 for spec in specs)
    assert all(spec["device"] == "cuda" for spec in specs)  # the study's device, unless --device says otherwise
    paper = next(spec for spec in specs if spec["algo"] == "offon_paper")
    assert module.run_dir(tmp_path, paper) == tmp_path / "toy_runs" / "offon_dqn" / f"{paper['env']}_{paper['seed']}"
    assert "--algo offon_paper" in " ".join(module.train_command(paper, "logs"))
    narrowed = module.build_specs(module.parse_args(["--study", str(study), "--algos", "dqn", "--seeds", "41-41"]))
    assert {(spec["algo"], spec["seed"]) for spec in narrowed} == {("dqn", 41)}
    with pytest.raises(SystemExit):
        module.parse_args(["--study", str(study), "--algos", "qrdqn"])  # not in the study


def test_a_former_name_reads_its_new_names_file():
    grid_specs = load_script("grid_specs")
    assert grid_specs.config_file("tuned", "offon_lambda_choice") == grid_specs.config_file("tuned", "offon_dqn")
    assert grid_specs.config_file("tuned", "offon_lambda_choice").name == "offon_dqn.yml"
    assert grid_specs.config_file("paper", "offon_paper").parent.name == "paper"


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


def test_curves_title_names_the_settings_the_runs_trained_with():
    module = load_script("plot")

    def runs(*settings: str) -> dict:
        return {"dqn": [module.Run("dqn", "Acrobot-v1", 0, 100, np.array([100]), np.array([0.0]), None, s) for s in settings]}

    assert module.curves_title("Acrobot-v1", runs("tuned", "tuned"), "headtohead2") == (
        "Acrobot-v1: 'tuned' settings\ngrid 'headtohead2'"
    )
    assert module.curves_title("Acrobot-v1", runs("tuned"), "tuned") == "Acrobot-v1: 'tuned' settings"
    assert module.curves_title("Acrobot-v1", runs(""), "paper") == "Acrobot-v1: 'paper' settings"  # not recorded
    mixed = module.curves_title("Acrobot-v1", runs("paper", "tuned"), "mixed")
    assert mixed == "Acrobot-v1: 'paper', 'tuned' settings\ngrid 'mixed'"
    lunar = module.curves_title("LunarLander-v3", runs("paper"), "paper")
    assert lunar == f"LunarLander-v3: 'paper' settings, as the paper's {module.PAPER_FIGURES['LunarLander-v3']}"
