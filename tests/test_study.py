"""``scripts/study.py``: a study file judged from hand-made run folders, against verdicts and IQMs computed by hand."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import load_script

ENVS = ["CartPole-v1", "Acrobot-v1"]
SEEDS = [1, 2, 3, 4]
STUDY = {
    "name": "toy",
    "question": "Does the candidate hold against DQN?",
    "stated": "2026-11-27",
    "algos": ["dqn", "offon_lambda_choice"],
    "envs": ENVS,
    "seeds": SEEDS,
    "final_evaluations": 2,
    "normalisation": {env: [0.0, 10.0] for env in ENVS},
    "bootstrap_reps": {"difference": 2000, "iqm": 500},
    "candidate": "offon_lambda_choice",
    "rule": [
        {"kind": "final_not_below", "reference": "dqn"},
        {"kind": "iqm_above", "measure": "auc", "reference": "dqn"},
    ],
    "setup_check": {"algo": "dqn", "seeds": [0], "name": "toy_check"},
}


def write_run(root: Path, grid: str, algo: str, env: str, seed: int, returns: list[list[float]]) -> None:
    """A finished run as scripts/benchmark.py writes it: evaluations every 10 steps, a monitor file, done.json."""
    folder = root / grid / algo / f"{env.replace('/', '-')}_{seed}"
    folder.mkdir(parents=True)
    timesteps = [10 * (index + 1) for index in range(len(returns))]
    np.savez(folder / "evaluations.npz", timesteps=np.array(timesteps), results=np.array(returns, dtype=float))
    (folder / "0.monitor.csv").write_text('#{"t_start": 0}\nr,l,t\n1.0,10,0.1\n')
    spec = {"set": "tuned", "grid": grid, "algo": algo, "env": env, "seed": seed, "n_timesteps": timesteps[-1]}
    (folder / "done.json").write_text(json.dumps({"spec": spec, "returncode": 0, "n_evaluations": len(timesteps)}))


def write_study(tmp_path: Path, candidate: dict[str, list[float]]) -> tuple[Path, Path]:
    """DQN's runs hold 1, 2, 3, 4 (by seed) at every evaluation on both envs; the candidate's hold ``candidate[env]``."""
    root = tmp_path / "raw"
    for env in ENVS:
        for seed, dqn_value, candidate_value in zip(SEEDS, [1.0, 2.0, 3.0, 4.0], candidate[env], strict=True):
            write_run(root, "toy", "dqn", env, seed, [[dqn_value, dqn_value]] * 3)
            write_run(root, "toy", "offon_lambda_choice", env, seed, [[candidate_value, candidate_value]] * 3)
    path = tmp_path / "toy.yml"
    path.write_text(yaml.safe_dump(STUDY))
    return path, root


def test_a_rule_that_holds(tmp_path: Path) -> None:
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    study = study_module.Study.read(path)
    runs, scores = study_module.study_runs(study, root)
    # Normalised AUC (value / 10) over both envs: 0.3, 0.3, 0.4, 0.4, 0.5, 0.5, 0.6, 0.6, whose middle half has mean 0.45
    iqms = study_module.iqm_intervals(study, runs, scores, "auc")
    assert iqms["offon_lambda_choice"][0] == pytest.approx(0.45) and iqms["dqn"][0] == pytest.approx(0.25)
    assert iqms["dqn"][1] <= 0.25 <= iqms["dqn"][2]
    decision, lines = study_module.verdict(study, runs, scores)
    assert decision == "holds", lines
    assert lines[0].startswith("holds: final return not below DQN's") and "0.450" in lines[1]
    # The report writes its table and figures, and names the verdict
    assert study_module.report(study, root, tmp_path / "report") == "holds"
    table = (tmp_path / "report" / "table.md").read_text()
    assert "**Verdict: holds.**" in table and "2.00 [" in table  # the candidate's mean final minus DQN's: +2
    assert (tmp_path / "report" / "curves.png").is_file() and (tmp_path / "report" / "aggregate.png").is_file()


def test_a_final_return_below_the_reference_on_one_env(tmp_path: Path) -> None:
    study_module = load_script("study")
    path, root = write_study(tmp_path, {"CartPole-v1": [3.0, 4.0, 5.0, 6.0], "Acrobot-v1": [-10.0, -9.0, -8.0, -7.0]})
    study = study_module.Study.read(path)
    decision, lines = study_module.verdict(study, *study_module.study_runs(study, root))
    # Acrobot-v1: -8.5 against 2.5, all four seeds below all four of DQN's: the interval is below zero
    assert decision == "does not hold"
    assert lines[0].startswith("does not hold:") and "below on Acrobot-v1 (-11.00" in lines[0]


def test_missing_runs_leave_the_verdict_open(tmp_path: Path) -> None:
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    (root / "toy" / "dqn" / "Acrobot-v1_4" / "done.json").unlink()
    study = study_module.Study.read(path)
    decision, lines = study_module.verdict(study, *study_module.study_runs(study, root))
    assert decision == "incomplete (1 runs missing)"
    assert all(line.startswith("open:") for line in lines)


def test_setup_check_against_a_random_policy(tmp_path: Path) -> None:
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    # Seed 0 of the check: CartPole-v1 well above the random policy, Acrobot-v1 at its level
    write_run(root, "toy_check", "dqn", "CartPole-v1", 0, [[0.0, 0.0], [5.0, 6.0], [7.0, 8.0]])
    write_run(root, "toy_check", "dqn", "Acrobot-v1", 0, [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    random = {env: {"mean": 0.5, "low": 0.2, "high": 0.8} for env in ENVS}
    passed, lines = study_module.setup_check(study_module.Study.read(path), root, random)
    assert not passed
    assert lines[0].endswith(": above") and "6.50" in lines[0]  # the last two evaluations' four episodes: 5, 6, 7, 8
    assert lines[1].endswith(": NOT above")


def test_the_minatar_study_file_reads() -> None:
    study_module = load_script("study")
    study = study_module.Study.read(Path(__file__).parents[1] / "benchmarks" / "minatar.yml")
    assert study.seeds == [40, 41, 42, 43, 44] and len(study.envs) == 5 and study.candidate == "offon_lambda_choice"
    assert set(study.normalisation) == set(study.envs)
    assert all(low < high for low, high in study.normalisation.values())
    assert [criterion["kind"] for criterion in study.rule] == ["final_not_below", "iqm_above"]
