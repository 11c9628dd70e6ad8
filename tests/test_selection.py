"""``scripts/selection.py``: studies that choose among candidates (the search), from hand-made runs and the committed ones."""

from pathlib import Path

import pytest
import yaml
from helpers import load_script
from test_study import write_run

ENVS = ["CartPole-v1", "Acrobot-v1"]
SEEDS = [0, 1, 2]
RANGES = {"CartPole-v1": [0.0, 500.0], "Acrobot-v1": [-500.0, 0.0]}


def selection_study(tmp_path: Path, finals: dict[str, dict[str, list[float]]], **extra) -> tuple[Path, Path]:
    """Candidates whose runs hold ``finals[name][env]`` (one value per seed) at every evaluation; ``dqn`` the reference."""
    root = tmp_path / "raw"
    for name, by_env in finals.items():
        for env, values in by_env.items():
            for seed, value in zip(SEEDS, values, strict=False):
                write_run(root, f"search/{name}/tuned", "dqn" if name == "dqn" else "offon_dqn", env, seed, [[value]] * 3)
    study = {
        "name": "toy_search",
        "question": "Which candidate?",
        "stated": "2026-11-27",
        "envs": ENVS,
        "seeds": SEEDS,
        "normalisation": RANGES,
        "ceilings": {"CartPole-v1": 500.0},
        "candidates": {
            name: {"algo": "dqn" if name == "dqn" else "offon_dqn", "folder": f"search/{name}/tuned", "description": name}
            for name in finals
        },
        "references": ["dqn"],
        "rule": [{"kind": "final_within", "reference": "dqn", "margin": 0.02}],
        "choose": {"measure": "auc", "envs": ENVS, "against": ["dqn"]},
        **extra,
    }
    path = tmp_path / "toy_search.yml"
    path.write_text(yaml.safe_dump(study, sort_keys=False))
    return path, root


def choose(tmp_path: Path, path: Path, root: Path) -> tuple[str, str]:
    study_module = load_script("study")
    decision = study_module.report(study_module.Study.read(path), root, tmp_path / "out")
    return decision, (tmp_path / "out" / "toy_search.md").read_text()


def test_the_highest_mean_among_those_that_pass(tmp_path: Path) -> None:
    dqn = {"CartPole-v1": [200.0] * 3, "Acrobot-v1": [-200.0] * 3}
    finals = {
        "dqn": dqn,
        # Normalised: CartPole 0.5, Acrobot 0.8 -> 0.65; passes (above DQN everywhere)
        "steady": {"CartPole-v1": [250.0] * 3, "Acrobot-v1": [-100.0] * 3},
        # Mean (1.0 + 0.578) / 2 = 0.789, the highest, but 11 below DQN on Acrobot-v1, where the bar is 10 below
        "fast": {"CartPole-v1": [500.0] * 3, "Acrobot-v1": [-211.0] * 3},
        # Exactly at the bar on Acrobot-v1: passes, mean (0.4 + 0.58) / 2 = 0.49
        "at_the_bar": {"CartPole-v1": [200.0] * 3, "Acrobot-v1": [-210.0] * 3},
    }
    path, root = selection_study(tmp_path, finals)
    decision, table = choose(tmp_path, path, root)
    assert decision == "steady, 0.650, above dqn's 0.500"
    assert "| fast | fast |" in table and "| 0.789 | no: final_within |" in table
    assert "| at_the_bar | at_the_bar |" in table and table.count("| yes |") == 2
    assert "| dqn | dqn |" in table and "(reference) |" in table
    assert (tmp_path / "out" / "curves.png").is_file()  # every candidate's learning curves beside the table


def test_missing_runs_decide_only_what_they_cannot_change(tmp_path: Path) -> None:
    dqn = {"CartPole-v1": [450.0] * 3, "Acrobot-v1": [-200.0] * 3}
    finals = {
        "dqn": dqn,
        "steady": {"CartPole-v1": [450.0] * 3, "Acrobot-v1": [-200.0] * 3},
        # Two CartPole runs at 100: even a third at the ceiling (500) leaves the mean at 233, below the bar of 440
        "hopeless": {"CartPole-v1": [100.0, 100.0], "Acrobot-v1": [-200.0] * 3},
    }
    path, root = selection_study(tmp_path, finals)
    decision, table = choose(tmp_path, path, root)
    assert decision.startswith("steady,")
    assert "CartPole-v1 (out of reach with 1 runs missing)" in table
    # An env without a ceiling waits for its runs: the choice waits too
    finals["waiting"] = {"CartPole-v1": [450.0] * 3, "Acrobot-v1": [-200.0, -200.0]}
    path, root = selection_study(tmp_path / "again", finals)
    decision, table = choose(tmp_path / "again", path, root)
    assert decision == "pending (2 of 3 candidates decided)" and "| waiting | waiting |" in table


def test_a_choice_per_env(tmp_path: Path) -> None:
    finals = {
        "n3": {"CartPole-v1": [100.0] * 3, "Acrobot-v1": [-100.0] * 3},
        "n10": {"CartPole-v1": [300.0] * 3, "Acrobot-v1": [-150.0] * 3},
    }
    path, root = selection_study(tmp_path, finals, choose={"measure": "auc", "per_env": True}, references=[], rule=[])
    decision, table = choose(tmp_path, path, root)
    assert decision == "per env"
    assert "| CartPole-v1 | 300 / 300 (3) | 100 / 100 (3) | n10 |" not in table  # columns follow the file's order
    assert "| CartPole-v1 | 100 / 100 (3) | 300 / 300 (3) | n10 |" in table
    assert "| Acrobot-v1 | -100 / -100 (3) | -150 / -150 (3) | n3 |" in table


def test_an_option_taken_per_env_against_its_absence(tmp_path: Path) -> None:
    finals = {
        "uniform": {"CartPole-v1": [100.0, 110.0, 120.0], "Acrobot-v1": [-100.0, -110.0, -120.0]},
        # CartPole: above on every seed, the difference's interval above 0; Acrobot: a higher mean from one seed only
        "prioritised": {"CartPole-v1": [200.0, 210.0, 220.0], "Acrobot-v1": [-60.0, -150.0, -121.0]},
    }
    path, root = selection_study(
        tmp_path, finals, choose={"pairs": {"prioritised": "uniform"}}, references=["uniform"], rule=[]
    )
    decision, table = choose(tmp_path, path, root)
    assert decision == "prioritised on CartPole-v1"
    rows = {line.split(" | ")[2]: line for line in table.splitlines() if line.startswith("| prioritised | uniform |")}
    assert rows["CartPole-v1"].startswith("| prioritised | uniform | CartPole-v1 | 210.00 [")
    assert "| 100.00 [86.67, 113.33] |" in rows["CartPole-v1"] and rows["CartPole-v1"].endswith("| yes |")
    # Mean -110.33 against -110: above by the mean, but the difference's interval spans 0
    assert rows["Acrobot-v1"].endswith("| no |") and "-110.33 [" in rows["Acrobot-v1"]
    (root / "search/uniform/tuned/offon_dqn/Acrobot-v1_2/done.json").unlink()
    decision, table = choose(tmp_path, path, root)
    assert decision == "pending (1 env pairs without all their runs)"


def test_the_runner_runs_each_candidate_with_its_settings(tmp_path: Path) -> None:
    module = load_script("benchmark")
    study = {
        "name": "toy_search",
        "settings": "tuned",
        "envs": ["CartPole-v1", "FrozenLake-v1"],
        "seeds": [0, 1],
        "seeds_on": {"FrozenLake-v1": [0, 1, 2]},
        "evaluation": {"episodes": 10, "episodes_on": {"FrozenLake-v1": 50}},
        "candidates": {
            "paper": {
                "algo": "offon_paper",
                "run_name": "offon_dqn",
                "folder": "tuned",
                "folder_on": {"FrozenLake-v1": "s/p"},
            },
            "ramp": {"algo": "offon_lambda", "hyperparams": ["mc_initial_prob:0.9"], "per_env": {"CartPole-v1": ["x:1"]}},
            "nstep10": {"algo": "dqn_nstep", "envs": ["CartPole-v1"], "seeds": [7], "folder": "s/n"},
        },
    }
    path = tmp_path / "toy_search.yml"
    path.write_text(yaml.safe_dump(study))
    specs = module.candidate_specs(module.parse_args(["--study", str(path)]))
    by_key = {(spec["algo"], spec["env"], spec["seed"]): spec for spec in specs}
    assert len(specs) == 2 + 3 + 2 + 3 + 1
    paper = by_key[("offon_paper", "CartPole-v1", 0)]
    assert module.run_dir(tmp_path, paper) == tmp_path / "tuned" / "offon_dqn" / "CartPole-v1_0"
    lake = by_key[("offon_paper", "FrozenLake-v1", 2)]
    assert module.run_dir(tmp_path, lake) == tmp_path / "s/p" / "offon_dqn" / "FrozenLake-v1_2"
    assert lake["eval_episodes"] == 50 and paper["eval_episodes"] == 10
    assert by_key[("offon_lambda", "CartPole-v1", 1)]["hyperparams"] == ["mc_initial_prob:0.9", "x:1"]
    assert by_key[("offon_lambda", "FrozenLake-v1", 1)]["hyperparams"] == ["mc_initial_prob:0.9"]
    assert by_key[("offon_lambda", "CartPole-v1", 1)]["grid"] == "toy_search"  # the study's folder by default
    assert module.run_dir(tmp_path, by_key[("dqn_nstep", "CartPole-v1", 7)]).parent == tmp_path / "s/n" / "dqn_nstep"


# The search's stages: every committed table written again from the committed runs, and the published choices
STAGES = {
    "search_coinflips": "mc_sample, 0.688",
    "search_nstep": "per env",
    "search_observed_bounds": "none",
    "search_lambda": "none",
    "search_lambda_to_qlearning": "none",
    "search_screen": "lambda90_peng_r5, 0.822, above nstep10's 0.820, above dqn_r5's 0.484",
}


@pytest.mark.parametrize("name", sorted(STAGES))
def test_the_search_stages_as_published(tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    study_module = load_script("study")
    monkeypatch.chdir(Path(__file__).parents[1])  # the study file's path as the committed table names it
    decision = study_module.report(study_module.Study.read(Path("benchmarks") / f"{name}.yml"), Path("results/raw"), tmp_path)
    assert decision == STAGES[name]
    committed = Path("results") / "search" / f"{name}.md"
    assert (tmp_path / f"{name}.md").read_text() == committed.read_text()
    if name == "search_nstep":
        assert (tmp_path / f"{name}.md").read_text().count(" | nstep10 |") == 4  # n = 10 on every benchmark task
