"""``scripts/docs_table.py`` on a tiny fake results folder, against mean ± std computed by hand."""

import json
from pathlib import Path

import numpy as np
from helpers import load_script


def fake_run(root: Path, algo: str, seed: int, timesteps: list[int], returns: list[list[float]], returncode: int = 0) -> None:
    folder = root / "tuned" / algo / f"CartPole-v1_{seed}"
    folder.mkdir(parents=True)
    np.savez(folder / "evaluations.npz", timesteps=np.array(timesteps), results=np.array(returns))
    spec = {"set": "tuned", "algo": algo, "env": "CartPole-v1", "seed": seed, "n_timesteps": 30}
    record = {"spec": spec, "returncode": returncode, "n_evaluations": len(timesteps)}
    (folder / "done.json").write_text(json.dumps(record))


def test_table_mean_std(tmp_path):
    # Two evaluation episodes per evaluation: their means are 1, 2, 4 (seed 0) and 3, 3, 6 (seed 1)
    fake_run(tmp_path, "offon_dqn", 0, [10, 20, 30], [[0, 2], [2, 2], [3, 5]])
    fake_run(tmp_path, "offon_dqn", 1, [10, 20, 30], [[3, 3], [2, 4], [6, 6]])
    # A failed run is left out
    fake_run(tmp_path, "offon_dqn", 2, [10, 20, 30], [[100, 100], [100, 100], [100, 100]], returncode=1)
    # DQN's seed 0 stopped early: its curve keeps its last value (5) at step 30
    fake_run(tmp_path, "dqn", 0, [10, 20], [[1, 1], [5, 5]])
    fake_run(tmp_path, "dqn", 1, [10, 20, 30], [[1, 1], [1, 1], [1, 1]])

    lines = load_script("docs_table").table(tmp_path, "tuned", ["offon_dqn", "dqn"]).splitlines()

    assert lines[0] == "| Env | Budget | Seeds | Metric | Off-On DQN | DQN |"
    # Final: 4 and 6, mean 5, std sqrt(2) = 1.41. DQN: 5 and 1, mean 3, std sqrt(8) = 2.83
    assert lines[2] == "| CartPole-v1 | 30 | 0-1 | final | 5.0 ± 1.4 | 3.0 ± 2.8 |"
    # AUC (trapezoids over 20 steps): (15 + 30) / 20 = 2.25 and (30 + 45) / 20 = 3.75, mean 3, std 1.06.
    # DQN: (30 + 50) / 20 = 4 and 1, mean 2.5, std 2.12
    assert lines[3] == "| CartPole-v1 | 30 | 0-1 | AUC | 3.0 ± 1.1 | 2.5 ± 2.1 |"
    assert len(lines) == 4


def test_table_missing_algorithm_and_unequal_seeds(tmp_path):
    fake_run(tmp_path, "offon_dqn", 0, [10, 20, 30], [[1, 1], [2, 2], [4, 4]])
    fake_run(tmp_path, "offon_dqn", 1, [10, 20, 30], [[3, 3], [3, 3], [6, 6]])
    fake_run(tmp_path, "dqn", 0, [10, 20, 30], [[1, 1], [1, 1], [2, 2]])

    lines = load_script("docs_table").table(tmp_path, "tuned", ["offon_dqn", "dqn", "dqn_mc"]).splitlines()

    # One seed: the mean alone; no run: n/a; seeds differ between algorithms: the counts of those present
    assert lines[2] == "| CartPole-v1 | 30 | 2/1 | final | 5.0 ± 1.4 | 2.0 | n/a |"
