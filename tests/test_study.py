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


def test_a_configuration_in_its_own_folder_judged_against_committed_runs(tmp_path: Path) -> None:
    """``candidates`` with a ``candidate`` among them: a head-to-head (the verdict and table.md, not a choice), each
    name's runs read from its own folder under its algorithm's name, the configuration's settings passed to its runs."""
    study_module = load_script("study")
    grid_specs = load_script("grid_specs")
    _, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})  # dqn's and a former candidate's runs
    for env in ENVS:
        for seed, value in zip(SEEDS, [2.0, 3.0, 4.0, 5.0], strict=True):
            write_run(root, "search/horizon", "offon_qrdqn", env, seed, [[value, value]] * 3)
    study_file = {key: value for key, value in STUDY.items() if key not in ("algos", "setup_check")}
    study_file["candidates"] = {
        "horizon": {"algo": "offon_qrdqn", "hyperparams": ["mc_initial_prob:0.670"], "folder": "search/horizon"},
        "dqn": {"algo": "dqn", "folder": "toy"},
        "offon_lambda_choice": {"algo": "offon_lambda_choice", "folder": "toy"},
    }
    study_file["candidate"] = "horizon"
    study_file["also_against"] = ["offon_lambda_choice"]
    study_file["labels"] = {"horizon": "OffOnQRDQN (lambda_3)"}
    path = tmp_path / "judgement.yml"
    path.write_text(yaml.safe_dump(study_file))
    study = study_module.Study.read(path)
    runs, scores = study_module.study_runs(study, root)
    assert [run.seed for run in runs["CartPole-v1"]["horizon"]] == SEEDS
    assert scores["CartPole-v1"]["horizon"]["final"].tolist() == [2.0, 3.0, 4.0, 5.0]
    assert scores["CartPole-v1"]["offon_lambda_choice"]["final"].tolist() == [3.0, 4.0, 5.0, 6.0]
    # Against DQN (1, 2, 3, 4): 1 above on every seed, so the rule holds; the former candidate is 1 above it, so
    # its IQM of normalised AUC (0.35 against 0.45, as in test_a_rule_that_holds) is not above that one's
    assert study_module.report(study, root, tmp_path / "report") == "holds"
    table = (tmp_path / "report" / "table.md").read_text()
    assert "**Verdict: holds.** The rule" in table and "for OffOnQRDQN (lambda_3):" in table
    assert "- reported, not part of the rule, against Off-On λ (search's choice):" in table
    assert "  - does not hold: IQM of normalised AUC above Off-On λ (search's choice)'s: 0.350" in table
    assert not (tmp_path / "report" / "judgement.md").exists()  # no choice among candidates written
    # An interim look on seeds 1-2: the configuration's normalised AUC over both envs is 0.2, 0.2, 0.3, 0.3 (IQM 0.25),
    # DQN's 0.1, 0.1, 0.2, 0.2 (0.15); a search whose candidates have seeds of their own is not narrowed
    narrowed = study_module.seed_subset(study, [1, 2])
    iqms = study_module.iqm_intervals(narrowed, *study_module.study_runs(narrowed, root), "auc")
    assert iqms["horizon"][0] == pytest.approx(0.25) and iqms["dqn"][0] == pytest.approx(0.15)
    assert study_module.report(narrowed, root, tmp_path / "interim") == "holds"
    with_own_seeds = {**study_file["candidates"], "horizon": {**study_file["candidates"]["horizon"], "seeds": [1, 2]}}
    path.write_text(yaml.safe_dump({**study_file, "candidates": with_own_seeds}))
    with pytest.raises(ValueError, match=r"candidates have no seeds of their own \(horizon\)"):
        study_module.seed_subset(study_module.Study.read(path), [1])
    # A candidate that is not one of the candidates is refused
    path.write_text(yaml.safe_dump({**study_file, "candidate": "horizon_typo"}))
    with pytest.raises(ValueError, match="the candidate 'horizon_typo' is not one of the algos"):
        study_module.Study.read(path)
    # The runner gives the configuration its settings and its folder, the others theirs
    specs = grid_specs.candidate_specs(
        grid_specs.argparse.Namespace(
            study_file=study,
            algos=["horizon"],
            envs=ENVS,
            seeds=SEEDS,
            seeds_given=False,
            set="tuned",
            n_timesteps=None,
            n_evals=2,
            eval_freq=None,
            eval_episodes=5,
            hyperparams=[],
            name=None,
            run_names={},
            device="cpu",
            threads=1,
            timeout=None,
            checkpoint_freq=0,
            root=root,
        )
    )
    assert {(spec["grid"], spec["algo"], tuple(spec["hyperparams"])) for spec in specs} == {
        ("search/horizon", "offon_qrdqn", ("mc_initial_prob:0.670",))
    }


def test_the_report_names_the_runs_resumed_from_a_checkpoint(tmp_path: Path) -> None:
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    study_module.report(study_module.Study.read(path), root, tmp_path / "before")
    assert "resumed" not in (tmp_path / "before" / "table.md").read_text()
    done = root / "toy" / "dqn" / "Acrobot-v1_2" / "done.json"
    done.write_text(json.dumps({**json.loads(done.read_text()), "resumed_at": [10, 20]}))
    study_module.report(study_module.Study.read(path), root, tmp_path / "after")
    table = (tmp_path / "after" / "table.md").read_text()
    assert "Runs resumed from a checkpoint after an interruption (step): DQN on Acrobot-v1, seed 2 (at 10, 20)." in table


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


def test_the_runs_so_far_paired_by_seed(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch) -> None:
    """``--by-seed``: a row per run of the candidate, the reference's and the others' runs on its seed beside it (final /
    AUC, both the run's constant value here), "-" where that run is not in; nothing written."""
    study_module = load_script("study")
    path, root = write_study(tmp_path, {"CartPole-v1": [3.0, 4.0, 5.0, 6.0], "Acrobot-v1": [7.0, 8.0, 9.0, 10.0]})
    path.write_text(yaml.safe_dump({**STUDY, "algos": [*STUDY["algos"], "qrdqn"], "also_against": ["qrdqn"]}))
    write_run(root, "toy", "qrdqn", "Acrobot-v1", 2, [[0.5, 0.5]] * 3)
    (root / "toy" / "offon_lambda_choice" / "CartPole-v1_3" / "done.json").unlink()
    (root / "toy" / "dqn" / "Acrobot-v1_4" / "done.json").unlink()
    monkeypatch.chdir(tmp_path)
    assert study_module.main([str(path), "--root", str(root), "--by-seed"]) == "by seed"
    lines = capsys.readouterr().out.splitlines()
    study = study_module.Study.read(path)
    assert lines[0] == f"| env | seed | {study.label('offon_lambda_choice')} | DQN | QR-DQN |"  # candidate, reference, other
    assert lines[2:] == [
        "| CartPole-v1 | 1 | 3.00 / 3.00 | 1.00 / 1.00 | - |",
        "| CartPole-v1 | 2 | 4.00 / 4.00 | 2.00 / 2.00 | - |",
        "| CartPole-v1 | 4 | 6.00 / 6.00 | 4.00 / 4.00 | - |",
        "| Acrobot-v1 | 1 | 7.00 / 7.00 | 1.00 / 1.00 | - |",
        "| Acrobot-v1 | 2 | 8.00 / 8.00 | 2.00 / 2.00 | 0.50 / 0.50 |",
        "| Acrobot-v1 | 3 | 9.00 / 9.00 | 3.00 / 3.00 | - |",
        "| Acrobot-v1 | 4 | 10.00 / 10.00 | - | - |",
    ]
    assert not (tmp_path / "results").exists()


def test_the_verdict_waits_only_for_the_runs_its_rule_reads(tmp_path: Path) -> None:
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    # QR-DQN is reported against, not judged by: none of its runs is in yet, and one of DQN's is gone
    with_other = {**STUDY, "algos": [*STUDY["algos"], "qrdqn"], "also_against": ["qrdqn"]}
    path.write_text(yaml.safe_dump(with_other))
    study = study_module.Study.read(path)
    decision, lines = study_module.verdict(study, *study_module.study_runs(study, root))
    assert decision == "holds", lines
    table = study_module.report(study, root, tmp_path / "report")
    text = (tmp_path / "report" / "table.md").read_text()
    assert table == "holds" and "**Verdict: holds.**" in text and "  - open: " in text  # against QR-DQN: open
    (root / "toy" / "dqn" / "Acrobot-v1_4" / "done.json").unlink()
    decision, _ = study_module.verdict(study, *study_module.study_runs(study, root))
    assert decision == "incomplete (1 runs missing)"
    # Normalised over every algorithm's runs (minmax), QR-DQN's runs change the candidate's scores: the verdict waits
    path.write_text(yaml.safe_dump({**with_other, "normalisation": "minmax"}))
    write_study(tmp_path / "again", {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    study = study_module.Study.read(path)
    decision, _ = study_module.verdict(study, *study_module.study_runs(study, tmp_path / "again" / "raw"))
    assert decision == "incomplete (8 runs missing)"


def test_every_algorithm_is_read_against_the_rules_reference(tmp_path: Path) -> None:
    """A rule that holds the candidate to QR-DQN: the report subtracts QR-DQN's final return from every other's too."""
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    for env in ENVS:
        for seed in SEEDS:
            write_run(root, "toy", "qrdqn", env, seed, [[7.0, 7.0]] * 3)  # 7 on every seed: means 2.5 (DQN), 4.5, 7
    rule = [{"kind": "final_not_below", "reference": "qrdqn"}, {"kind": "iqm_above", "measure": "auc", "reference": "qrdqn"}]
    path.write_text(yaml.safe_dump({**STUDY, "algos": [*STUDY["algos"], "qrdqn"], "rule": rule}))
    study = study_module.Study.read(path)
    assert study_module.difference_references(study) == ["dqn", "qrdqn"]
    assert study_module.report(study, root, tmp_path / "report") == "does not hold"
    table = (tmp_path / "report" / "table.md").read_text()
    minus_qrdqn = table.split("## Final return minus QR-DQN's")[1].split("##")[0]
    header = minus_qrdqn.strip().splitlines()[0]
    assert header == f"| env | DQN - QR-DQN | {study.label('offon_lambda_choice')} - QR-DQN |"
    # DQN 2.5 - 7 = -4.5 and the candidate 4.5 - 7 = -2.5 on both envs
    for env in ENVS:
        cells = next(line for line in minus_qrdqn.splitlines() if line.startswith(f"| {env} |")).split(" | ")
        assert cells[1].startswith("-4.50 [") and cells[2].startswith("-2.50 [")
    # The table against DQN stays as it was, QR-DQN in it at 7 - 2.5
    minus_dqn = table.split("## Final return minus DQN's")[1].split("##")[0]
    assert minus_dqn.strip().splitlines()[0] == f"| env | {study.label('offon_lambda_choice')} - DQN | QR-DQN - DQN |"
    assert "| +4.50 [" in minus_dqn


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
    # Its candidate runs under a former name; its tables call it what it is
    assert study.label("offon_lambda_choice") == "OffOnDQN (defaults)" and study.label("dqn") == "DQN"


def test_final_within_and_auc_apart_above_from_hand_made_runs(tmp_path: Path) -> None:
    """The first head-to-head's criteria: the bar (reference's mean final minus a share of the env's range) and the AUC
    intervals apart above the reference's on at least k envs."""
    study_module = load_script("study")
    path, root = write_study(tmp_path, {"CartPole-v1": [10.0, 11.0, 12.0, 13.0], "Acrobot-v1": [2.3, 2.3, 2.3, 2.3]})
    data = yaml.safe_load(path.read_text())
    # Ranges 0-10: the bar is DQN's mean (2.5) minus 0.2 = 2.3 on both envs
    data["ranges"] = {env: [0.0, 10.0] for env in ENVS}
    data["rule"] = [
        {"kind": "final_within", "reference": "dqn", "margin": 0.02},
        {"kind": "auc_apart_above", "reference": "dqn", "at_least": 1},
    ]
    path.write_text(yaml.safe_dump(data))
    study = study_module.Study.read(path)
    decision, lines = study_module.verdict(study, *study_module.study_runs(study, root))
    assert decision == "holds", lines
    assert "CartPole-v1 11.5 against the bar 2.3 (DQN 2.5)" in lines[0] and "Acrobot-v1 2.3 against the bar 2.3" in lines[0]
    # CartPole's AUC interval lies above DQN's; Acrobot's (2.3 on every seed) inside DQN's 1-4
    cartpole, acrobot = lines[1].split("; ")[1:]
    assert lines[1].startswith("holds:") and "on 1;" in lines[1]
    assert cartpole.startswith("CartPole-v1 [1") and cartpole.endswith("(above, apart)")
    assert acrobot.startswith("Acrobot-v1 [2.3, 2.3] against [") and acrobot.endswith("(overlapping)")
    data["rule"][1]["at_least"] = 2
    data["rule"][0]["margin"] = 0.019  # the bar 2.31: Acrobot-v1's 2.3 is below it
    path.write_text(yaml.safe_dump(data))
    decision, lines = study_module.verdict(study_module.Study.read(path), *study_module.study_runs(study, root))
    assert decision == "does not hold"
    assert lines[0].endswith("below on Acrobot-v1") and lines[1].startswith("does not hold: AUC interval")


def test_mean_above_with_a_margin_from_hand_made_runs(tmp_path: Path) -> None:
    """``mean_above`` with ``margin``: the candidate's mean normalised AUC over the envs against the reference's minus the
    margin (a setup check's "level with")."""
    study_module = load_script("study")
    # Candidate 2.0 on every seed and env: normalised 0.2; DQN's 1, 2, 3, 4: mean 2.5, normalised 0.25
    path, root = write_study(tmp_path, {env: [2.0, 2.0, 2.0, 2.0] for env in ENVS})
    data = yaml.safe_load(path.read_text())
    verdicts = {}
    for margin in (0.0, 0.049, 0.051):
        data["rule"] = [{"kind": "mean_above", "reference": "dqn", "measure": "auc", "margin": margin}]
        path.write_text(yaml.safe_dump(data))
        study = study_module.Study.read(path)
        verdicts[margin] = study_module.verdict(study, *study_module.study_runs(study, root))
    assert verdicts[0.0][0] == "does not hold" and verdicts[0.049][0] == "does not hold"
    assert verdicts[0.051][0] == "holds"
    assert verdicts[0.051][1][0] == "holds: mean normalised AUC above DQN's minus 0.051: 0.200 against 0.250"


def test_auc_not_below_reads_the_whole_curve(tmp_path: Path) -> None:
    """``auc_not_below``: the interval of the difference of mean AUCs, on every env. The candidate ends where DQN does
    on each seed (its final return is level) but starts at -10, so its AUC (the trapezoids' mean over three evaluations),
    (3 v - 10) / 4, lies below DQN's v: the mean difference is (3 * 2.5 - 10) / 4 - 2.5 = -3.125."""
    study_module = load_script("study")
    root = tmp_path / "raw"
    for env in ENVS:
        for seed, value in zip(SEEDS, [1.0, 2.0, 3.0, 4.0], strict=True):
            write_run(root, "toy", "dqn", env, seed, [[value, value]] * 3)
            write_run(root, "toy", "offon_lambda_choice", env, seed, [[-10.0, -10.0], [value, value], [value, value]])
    data = dict(STUDY, rule=[{"kind": "final_not_below", "reference": "dqn"}, {"kind": "auc_not_below", "reference": "dqn"}])
    path = tmp_path / "toy.yml"
    path.write_text(yaml.safe_dump(data))
    study = study_module.Study.read(path)
    decision, lines = study_module.verdict(study, *study_module.study_runs(study, root))
    assert decision == "does not hold"
    assert lines[0].startswith("holds: final return not below DQN's")
    assert lines[1].startswith("does not hold: AUC not below DQN's") and "Acrobot-v1 (-3.12 [" in lines[1]


def test_minmax_normalisation_and_former_run_names(tmp_path: Path) -> None:
    """``normalisation: minmax``: per env over every run of the study's algorithms (computed by hand here); runs made under
    a former name (``run_names``) count as the study's algorithm."""
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    (root / "toy" / "offon_lambda_choice").rename(root / "toy" / "old_name")
    for marker in (root / "toy" / "old_name").glob("*/done.json"):
        record = json.loads(marker.read_text())
        record["spec"]["algo"] = "old_name"
        marker.write_text(json.dumps(record))
    data = yaml.safe_load(path.read_text())
    data.update(normalisation="minmax", run_names={"offon_lambda_choice": "old_name"})
    path.write_text(yaml.safe_dump(data))
    study = study_module.Study.read(path)
    runs, scores = study_module.study_runs(study, root)
    assert [run.seed for run in runs["CartPole-v1"]["offon_lambda_choice"]] == SEEDS
    # Every env: scores 1..6 over both algorithms -> (x - 1) / 5; the candidate's 3, 3, 4, 4, 5, 5, 6, 6 -> middle half
    # 4, 4, 5, 5 -> (4.5 - 1) / 5 = 0.7; DQN's 1, 1, 2, 2, 3, 3, 4, 4 -> (2.5 - 1) / 5 = 0.3
    iqms = study_module.iqm_intervals(study, runs, scores, "auc")
    assert iqms["offon_lambda_choice"][0] == pytest.approx(0.7) and iqms["dqn"][0] == pytest.approx(0.3)
    report = study_module.report(study, root, tmp_path / "report")
    assert report == "holds" and "over every run of the study there" in (tmp_path / "report" / "table.md").read_text()


def test_interval_estimates_do_not_depend_on_the_other_algorithms() -> None:
    """An algorithm's interval is drawn from its own seeded resamples, whatever else is estimated with it."""
    run_stats = load_script("run_stats")
    rng = np.random.default_rng(0)
    ours, other = rng.random((10, 4)), rng.random((10, 4))

    def iqm(scores: np.ndarray) -> np.ndarray:
        return np.array([run_stats.metrics.aggregate_iqm(scores)])

    alone = run_stats.interval_estimates({"ours": ours}, iqm, 200)
    together = run_stats.interval_estimates({"other": other, "ours": ours}, iqm, 200)
    np.testing.assert_array_equal(alone[1]["ours"], together[1]["ours"])
    assert alone[0]["ours"] == together[0]["ours"]


# The committed studies: the reporter writes each committed table.md (and verdict.md) again from the committed runs
COMMITTED = ["paper", "tuned", "headtohead", "headtohead2", "minatar", "classic_qr"]


@pytest.mark.slow
@pytest.mark.parametrize("name", COMMITTED)
def test_the_reporter_reproduces_the_committed_report(tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    study_module = load_script("study")
    root = Path(__file__).parents[1]
    monkeypatch.chdir(root)  # the study file's path as the committed report names it: benchmarks/<name>.yml
    study = study_module.Study.read(Path("benchmarks") / f"{name}.yml")
    study_module.report(study, Path("results") / "raw", tmp_path)
    for generated in ("table.md", "verdict.md"):
        committed = root / "results" / name / generated
        if committed.is_file() or (tmp_path / generated).is_file():
            assert (tmp_path / generated).read_text() == committed.read_text(), generated


@pytest.mark.slow
def test_the_published_verdicts() -> None:
    """The head-to-heads' verdicts and the figures their reports quote, from the committed runs."""
    study_module = load_script("study")
    benchmarks, raw = Path(__file__).parents[1] / "benchmarks", Path(__file__).parents[1] / "results" / "raw"
    first = study_module.Study.read(benchmarks / "headtohead.yml")
    decision, lines = study_module.verdict(first, *study_module.study_runs(first, raw))
    assert decision == "does not hold"
    for quoted in (
        "CartPole-v1 410.2 against the bar 338.1 (DQN 348.1)",
        "LunarLander-v3 148.2 against the bar 169.7 (DQN 179.7)",
        "Acrobot-v1 -86.4 against the bar -85.8 (DQN -77.0)",
    ):
        assert quoted in lines[0]
    assert "on 2;" in lines[1] and "CartPole-v1 [421.9, 464.7] against [222.7, 263.8] (above, apart)" in lines[1]
    second = study_module.Study.read(benchmarks / "headtohead2.yml")
    decision, lines = study_module.verdict(second, *study_module.study_runs(second, raw))
    assert decision == "holds"
    assert lines[0].endswith("holds on every env")
    assert "0.865 [0.828, 0.898] against 0.803 [0.758, 0.847]" in lines[1]
    # MinAtar: the rule (against DQN) holds; against QR-DQN, reported beside it, neither criterion does
    minatar = study_module.Study.read(benchmarks / "minatar.yml")
    runs, scores = study_module.study_runs(minatar, raw)
    decision, lines = study_module.verdict(minatar, runs, scores)
    assert decision == "holds"
    assert lines[1] == "holds: IQM of normalised AUC above DQN's: 0.473 [0.406, 0.531] against 0.227 [0.174, 0.285]"
    # The rule's own criteria with QR-DQN as the reference, as the report's "also against" lines judge them
    (final_holds, final_line), (iqm_holds, _) = [
        study_module.judge_criterion(minatar, runs, scores, {**criterion, "reference": "qrdqn"}, minatar.candidate)
        for criterion in minatar.rule
    ]
    assert final_holds is False and iqm_holds is False and "MinAtar/SpaceInvaders-v0" not in final_line
    for game in ("Asterix", "Freeway", "Seaquest"):
        assert f"MinAtar/{game}-v0 (-" in final_line
    iqms = study_module.iqm_intervals(minatar, runs, scores, "auc")
    assert iqms["qrdqn"][1] > iqms["offon_lambda_choice"][2]  # QR-DQN's interval wholly above the defaults'


def test_a_single_seed_gives_no_interval_and_no_verdict(tmp_path: Path) -> None:
    # Far below DQN on Acrobot-v1, but with one run a side the difference has no interval: the criterion cannot pass
    study_module = load_script("study")
    root = tmp_path / "raw"
    for env, candidate_value in [("CartPole-v1", 5.0), ("Acrobot-v1", -9.0)]:
        write_run(root, "toy", "dqn", env, 1, [[2.0, 2.0]] * 3)
        write_run(root, "toy", "offon_lambda_choice", env, 1, [[candidate_value, candidate_value]] * 3)
    path = tmp_path / "toy.yml"
    path.write_text(yaml.safe_dump({**STUDY, "seeds": [1]}))
    study = study_module.Study.read(path)
    decision, lines = study_module.verdict(study, *study_module.study_runs(study, root))
    assert decision != "holds"
    assert lines[0] == (
        "open: final return not below DQN's on any env by the interval of the difference: "
        "no interval on CartPole-v1 (a side has a single run)"
    )


@pytest.mark.slow
def test_an_interim_look_on_the_seeds_every_run_is_in(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    (root / "toy" / "dqn" / "Acrobot-v1_4" / "done.json").unlink()
    monkeypatch.chdir(tmp_path)  # the default report folder, results/toy/..., lands here
    assert study_module.main([str(path), "--root", str(root)]) == "incomplete (1 runs missing)"
    # Seeds 1-3: every run in. The candidate's normalised AUC over both envs is 0.3, 0.3, 0.4, 0.4, 0.5, 0.5, whose
    # middle half (one trimmed at each end) has mean 0.4; DQN's 0.1, 0.1, 0.2, 0.2, 0.3, 0.3 has 0.2
    narrowed = study_module.seed_subset(study_module.Study.read(path), [1, 2, 3])
    assert narrowed.seeds == [1, 2, 3]
    iqms = study_module.iqm_intervals(narrowed, *study_module.study_runs(narrowed, root), "auc")
    assert iqms["offon_lambda_choice"][0] == pytest.approx(0.4) and iqms["dqn"][0] == pytest.approx(0.2)
    assert study_module.main([str(path), "--root", str(root), "--seeds", "3", "1", "2"]) == "holds"
    table = (tmp_path / "results" / "toy" / "seeds_1_2_3" / "table.md").read_text()
    assert table.startswith(f"<!-- Generated by python scripts/study.py {path.as_posix()} --seeds 1 2 3:")
    assert "# toy: 12 of 12 runs" in table and "An interim look at seeds 1, 2, 3 only, not the study's verdict" in table
    assert "| 0.400 [" in table  # the candidate's IQM of normalised AUC on the three seeds
    assert "**On seeds 1, 2, 3 only: holds.**" in table and "**Verdict:" not in table
    # The study's own report is not overwritten by the interim one
    assert "**Verdict: incomplete (1 runs missing).**" in (tmp_path / "results" / "toy" / "table.md").read_text()
    with pytest.raises(SystemExit):
        study_module.main([str(path), "--root", str(root), "--seeds", "1", "9"])  # 9 is not a seed of the study
    with pytest.raises(ValueError, match="not among the study's seeds"):
        study_module.seed_subset(study_module.Study.read(path), [9])


def test_an_interim_look_needs_a_seed_on_every_env(tmp_path: Path) -> None:
    # Seeds per env (``seeds_on``): seed 1 is CartPole-v1's only, so narrowing to it would leave Acrobot-v1 without a run
    study_module = load_script("study")
    path = tmp_path / "toy.yml"
    path.write_text(yaml.safe_dump({**STUDY, "seeds_on": {"CartPole-v1": [1, 2], "Acrobot-v1": [2, 3]}}))
    study = study_module.Study.read(path)
    assert study_module.seed_subset(study, [2]).seeds_on == {"CartPole-v1": [2], "Acrobot-v1": [2]}
    with pytest.raises(ValueError, match=r"none of \[1\] is a seed of Acrobot-v1"):
        study_module.seed_subset(study, [1])


def test_an_interim_look_is_named_by_the_seeds_asked_for(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Seed 5 is a seed of both envs through ``seeds_on`` only, not of the study's ``seeds``: the look is still on seed 5
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    path.write_text(yaml.safe_dump({**yaml.safe_load(path.read_text()), "seeds_on": {env: [1, 5] for env in ENVS}}))
    monkeypatch.chdir(tmp_path)
    study_module.main([str(path), "--root", str(root), "--seeds", "5"])
    table = (tmp_path / "results" / "toy" / "seeds_5" / "table.md").read_text()
    assert "An interim look at seeds 5 only" in table and "**On seeds 5 only:" in table and "**Verdict:" not in table


@pytest.mark.slow
def test_an_interim_look_on_the_envs_every_run_is_in(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    (root / "toy" / "dqn" / "Acrobot-v1_4" / "done.json").unlink()
    monkeypatch.chdir(tmp_path)
    # CartPole-v1: every run in. The candidate's normalised AUC there is 0.3, 0.4, 0.5, 0.6, whose middle half has mean
    # 0.45; DQN's 0.1, 0.2, 0.3, 0.4 has 0.25
    narrowed = study_module.env_subset(study_module.Study.read(path), ["CartPole-v1"])
    assert narrowed.envs == ["CartPole-v1"] and narrowed.normalisation == {"CartPole-v1": (0.0, 10.0)}
    iqms = study_module.iqm_intervals(narrowed, *study_module.study_runs(narrowed, root), "auc")
    assert iqms["offon_lambda_choice"][0] == pytest.approx(0.45) and iqms["dqn"][0] == pytest.approx(0.25)
    assert study_module.main([str(path), "--root", str(root), "--envs", "CartPole-v1"]) == "holds"
    table = (tmp_path / "results" / "toy" / "envs_CartPole-v1" / "table.md").read_text()
    assert table.startswith(f"<!-- Generated by python scripts/study.py {path.as_posix()} --envs CartPole-v1:")
    assert "# toy: 8 of 8 runs" in table
    assert "An interim look at CartPole-v1 only, not the study's verdict, which is on all its envs" in table
    assert "**On CartPole-v1 only: holds.**" in table and "| 0.450 [" in table and "Acrobot-v1" not in table
    # Both narrowed: seeds 1-3 on Acrobot-v1, named by both in the folder and the table
    assert study_module.main([str(path), "--root", str(root), "--seeds", "1", "2", "3", "--envs", "Acrobot-v1"]) == "holds"
    table = (tmp_path / "results" / "toy" / "seeds_1_2_3_envs_Acrobot-v1" / "table.md").read_text()
    assert "**On seeds 1, 2, 3 on Acrobot-v1 only: holds.**" in table and "all its seeds and envs" in table
    with pytest.raises(SystemExit):
        study_module.main([str(path), "--root", str(root), "--envs", "LunarLander-v3"])  # not an env of the study
    with pytest.raises(ValueError, match="not among the study's envs"):
        study_module.env_subset(study_module.Study.read(path), ["LunarLander-v3"])


@pytest.mark.slow
def test_the_benchmark_tables_name_algorithms_as_the_study_does(tmp_path: Path) -> None:
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    path.write_text(yaml.safe_dump({**STUDY, "tables": "benchmark", "labels": {"offon_lambda_choice": "The candidate"}}))
    assert study_module.report(study_module.Study.read(path), root, tmp_path / "report") == "holds"
    table = (tmp_path / "report" / "table.md").read_text()
    assert "| The candidate |" in table and "search's choice" not in table
    assert "for The candidate:" in (tmp_path / "report" / "verdict.md").read_text()
    assert study_module.plot.label("offon_lambda_choice") == "Off-On λ (search's choice)"  # the usual names back after it


def test_the_benchmarks_page_names_every_study_file() -> None:
    root = Path(__file__).resolve().parents[1]
    page = (root / "docs" / "benchmarks.md").read_text(encoding="utf-8")
    studies = sorted(path.stem for path in (root / "benchmarks").glob("*.yml"))
    assert studies, "the study files are in benchmarks/"
    assert [study for study in studies if f"`{study}`" not in page] == []


def test_every_algorithm_of_a_study_gets_its_own_colour() -> None:
    study_module = load_script("study")
    # A candidate named by its study came out in the colour cycle's first, DQN's blue, beside DQN itself
    algos = ["offon_qrdqn_cache_n3", "qrdqn_nstep", "qrdqn", "offon_qrdqn", "offon_lambda_choice", "dqn", "dqn_nstep"]
    colors = study_module.algo_colors(algos)
    assert sorted(colors) == sorted(algos)
    assert len(set(colors.values())) == len(algos) and all(str(color).startswith("tab:") for color in colors.values())
    assert colors["dqn"] == study_module.COLORS["dqn"] and colors["qrdqn_nstep"] == study_module.COLORS["qrdqn_nstep"]
    many = study_module.algo_colors([f"candidate_{index}" for index in range(10)])
    assert len(set(many.values())) == 10


def test_a_final_score_played_after_training_is_the_final_return_when_the_study_says_so(tmp_path: Path) -> None:
    """``final: final_evaluation``: each run's final return is the mean of its final_evaluation.npz episodes (the Atari
    100k protocol's score), not its last evaluations; ``published`` scores are tabled beside the study's."""
    study_module = load_script("study")
    path, root = write_study(tmp_path, {env: [3.0, 4.0, 5.0, 6.0] for env in ENVS})
    for env in ENVS:
        for seed in SEEDS:
            folder = root / "toy" / "offon_lambda_choice" / f"{env}_{seed}"
            np.savez(folder / "final_evaluation.npz", results=np.array([0.0, 2.0 * seed]), ep_lengths=np.array([5, 5]))
    data = {**yaml.safe_load(path.read_text()), "final": "final_evaluation", "published": {"DER": {"CartPole-v1": 7.5}}}
    path.write_text(yaml.safe_dump(data))
    study = study_module.Study.read(path)
    scores = study_module.study_runs(study, root)[1]
    # Seeds 1-4 played 0 and 2 x seed after training: means 1, 2, 3, 4; DQN has no such file: its last evaluations
    np.testing.assert_allclose(scores["CartPole-v1"]["offon_lambda_choice"]["final"], [1.0, 2.0, 3.0, 4.0])
    np.testing.assert_allclose(scores["CartPole-v1"]["dqn"]["final"], [1.0, 2.0, 3.0, 4.0])
    np.testing.assert_allclose(scores["CartPole-v1"]["offon_lambda_choice"]["auc"], [3.0, 4.0, 5.0, 6.0])
    study_module.report(study, root, tmp_path / "report")
    table = (tmp_path / "report" / "table.md").read_text()
    assert "## Final score (mean of the episodes played after training)" in table
    assert "| CartPole-v1 | 7.5 |" in table and "| Acrobot-v1 | - |" in table
    # Read without the key, the same runs are scored by their last evaluations
    data.pop("final")
    path.write_text(yaml.safe_dump(data))
    study = study_module.Study.read(path)
    np.testing.assert_allclose(
        study_module.study_runs(study, root)[1]["CartPole-v1"]["offon_lambda_choice"]["final"], [3, 4, 5, 6]
    )
