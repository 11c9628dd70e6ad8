"""The bundled hyperparameter files, the choice of file, and the Optuna samplers."""

import argparse
import importlib.util
from pathlib import Path
from typing import Any

import optuna
import pytest
import rl_zoo3
import yaml
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER
from stable_baselines3 import DQN

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.callbacks import GoalCountCallback, StopOnMeanTrainingReward
from sb3_offon.minatar_envs import minatar_ids
from sb3_offon.offon_dqn.offon_dqn import OFFON_PARAMETERS
from sb3_offon.qrdqn import QRDQN
from sb3_offon.variants import DQNMC, DQNSarsa
from sb3_offon.zoo import ALGOS, ALIASES, HYPERPARAMS_DIR, SAMPLERS, register, resolve_config

register()

PAPER_CLASSES = {"offon_paper": OffOnDQN, "dqn_mc": DQNMC, "dqn_sarsa": DQNSarsa, "dqn": DQN}
# The head-to-heads' baselines (n-step DQN, QR-DQN) have entries for the four benchmark tasks only
BASELINE_CLASSES = {"dqn_nstep": DQN, "qrdqn": QRDQN, "qrdqn_nstep": QRDQN, "offon_qrdqn": OffOnQRDQN}
# The configuration the search chose on tuning seeds 0-4: the four tasks and the search's stochastic one
CHOICE_CLASSES = {"offon_mc_decay": OffOnDQN}
# The lambda-return mode: OffOnDQN with mc_mixing="lambda" on the same tasks
LAMBDA_CLASSES = {"offon_watkins": OffOnDQN, "offon_dqn": OffOnDQN}
CLASSES = {**PAPER_CLASSES, **BASELINE_CLASSES, **CHOICE_CLASSES, **LAMBDA_CLASSES}
BASELINE_ENVS = {"default", "atari", "CartPole-v1", "MountainCar-v0", "LunarLander-v3", "Acrobot-v1"}
CHOICE_ENVS = BASELINE_ENVS | {"FrozenLake-v1"}
# The MinAtar games' entries (tests/test_minatar.py checks their values): in the files of the MinAtar head-to-head's
# algorithms, and in offon_watkins.yml, which offon_dqn.yml repeats entry for entry
MINATAR_ENVS = set(minatar_ids())
MINATAR_FILES = {"dqn", "dqn_nstep", "qrdqn", "qrdqn_nstep", "offon_qrdqn", "offon_paper", "offon_watkins", "offon_dqn"}
# The search's winner, `mc_sample` (results/search/README.md): the paper's delta1 schedule, no Sarsa, SB3's loss
CHOICE_TARGETS = dict(
    mc_initial_prob=0.99,
    mc_final_prob=0.01,
    mc_fraction=1.0,
    qlearning_initial_prob=1.0,
    qlearning_final_prob=1.0,
    mc_mixing="sample",
    mc_truncation="bootstrap",
    loss="huber",
)
REQUIRED_ENVS = {
    "CartPole-v1",
    "MountainCar-v0",
    "LunarLander-v3",
    "Acrobot-v1",
    "atari",
    "CartPoleFallPenalty-v1",
    "MountainCarGoalBonus-v0",
}
PAPER_ENVS = {
    "CartPole-v0",
    "CartPole-v1",
    "MountainCar-v0",
    "LunarLander-v3",
    "CartPoleFallPenalty-v1",
    "MountainCarGoalBonus-v0",
}
TARGET_KEYS = set(OFFON_PARAMETERS)
# Environments no entry names, to build the ``default`` entries with
UNLISTED_ENV = "CartPole-v0"
HAS_ALE = importlib.util.find_spec("ale_py") is not None


def load(path: Path) -> dict[str, Any]:
    with open(path) as file:
        return yaml.safe_load(file)


def entries() -> list[tuple[str, str, str]]:
    """Every (file set, algo, entry) pair: the main files and the paper's."""
    pairs = []
    for folder, name, algos in ((HYPERPARAMS_DIR, "main", CLASSES), (HYPERPARAMS_DIR / "paper", "paper", PAPER_CLASSES)):
        for algo in algos:
            pairs += [(name, algo, entry) for entry in load(folder / f"{algo}.yml")]
    return pairs


@pytest.mark.parametrize("folder", [HYPERPARAMS_DIR, HYPERPARAMS_DIR / "paper"])
def test_every_algorithm_has_its_entries(folder: Path) -> None:
    algos = CLASSES if folder == HYPERPARAMS_DIR else PAPER_CLASSES
    assert sorted(path.stem for path in folder.glob("*.yml") if path.name != "aliases.yml") == sorted(algos)
    for algo in PAPER_CLASSES:
        assert set(load(folder / f"{algo}.yml")) >= (REQUIRED_ENVS if folder == HYPERPARAMS_DIR else PAPER_ENVS), algo
    if folder == HYPERPARAMS_DIR:
        for algo in BASELINE_CLASSES:
            assert set(load(folder / f"{algo}.yml")) == BASELINE_ENVS | MINATAR_ENVS, algo
        for algo in CLASSES:
            has_minatar = MINATAR_ENVS <= set(load(folder / f"{algo}.yml"))
            assert has_minatar == (algo in MINATAR_FILES), algo
        assert set(load(folder / "offon_mc_decay.yml")) == CHOICE_ENVS


def test_baselines_are_the_zoo_settings() -> None:
    """n-step DQN is the zoo's DQN entry plus n_steps; QR-DQN the zoo's own tuned entries, unchanged."""
    dqn = load(HYPERPARAMS_DIR / "dqn.yml")
    for env_id, entry in load(HYPERPARAMS_DIR / "dqn_nstep.yml").items():
        if env_id in MINATAR_ENVS:
            continue
        assert entry["n_steps"] in (3, 5, 10), env_id
        assert {key: value for key, value in entry.items() if key != "n_steps"} == dqn[env_id], env_id
    zoo = load(Path(rl_zoo3.__file__).parent / "hyperparams" / "qrdqn.yml")
    ours = load(HYPERPARAMS_DIR / "qrdqn.yml")
    assert {env_id: ours[env_id] for env_id in BASELINE_ENVS} == {env_id: zoo[env_id] for env_id in BASELINE_ENVS}


def test_nstep_qrdqn_is_qrdqn_with_the_n_of_nstep_dqn() -> None:
    """Every qrdqn_nstep entry is the qrdqn entry, unchanged, plus the n_steps of dqn_nstep's entry for the same env."""
    qrdqn, nstep_dqn = load(HYPERPARAMS_DIR / "qrdqn.yml"), load(HYPERPARAMS_DIR / "dqn_nstep.yml")
    entries = load(HYPERPARAMS_DIR / "qrdqn_nstep.yml")
    assert set(entries) == set(qrdqn)
    for env_id, entry in entries.items():
        assert {key: value for key, value in entry.items() if key != "n_steps"} == qrdqn[env_id], env_id
        assert entry["n_steps"] == nstep_dqn[env_id]["n_steps"], env_id


def test_offon_qrdqn_has_qrdqns_settings() -> None:
    """
    offon_qrdqn.yml is qrdqn.yml entry for entry, plus on the MinAtar games the configuration the MinAtar horizon
    judgement ran (its candidate's --hyperparams: lambda 0, 3-step windows); elsewhere OffOnQRDQN's defaults.
    """
    judgement = yaml.safe_load((Path(__file__).parents[1] / "benchmarks" / "minatar_horizon_judgement.yml").read_text())
    candidate = judgement["candidates"][judgement["candidate"]]
    assert candidate["algo"] == "offon_qrdqn"
    judged = {key: yaml.safe_load(value) for key, value in (item.split(":", 1) for item in candidate["hyperparams"])}
    assert judged == {"mc_initial_prob": 0.0, "mc_final_prob": 0.0, "n_steps": 3}
    offon, qrdqn = load(HYPERPARAMS_DIR / "offon_qrdqn.yml"), load(HYPERPARAMS_DIR / "qrdqn.yml")
    assert set(offon) == set(qrdqn)
    for env_id, entry in offon.items():
        expected = {**qrdqn[env_id], **judged} if env_id.startswith("MinAtar/") else qrdqn[env_id]
        assert entry == expected, env_id
    # The comment above the entries gives the judgement's figures
    text = (HYPERPARAMS_DIR / "offon_qrdqn.yml").read_text()
    assert "0.828 [0.774, 0.875]" in text and "+12.77" in text


def test_nstep_entries_are_the_search_choice() -> None:
    """Each benchmark task's n_steps is the one the search chose (python scripts/study.py benchmarks/search_nstep.yml)."""
    report = (Path(__file__).parents[1] / "results" / "search" / "search_nstep.md").read_text()
    chosen = {}
    for row in report.splitlines():
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        if cells[0] in BASELINE_ENVS:
            chosen[cells[0]] = int(cells[-1].removeprefix("nstep"))
    entries = load(HYPERPARAMS_DIR / "dqn_nstep.yml")
    assert set(chosen) == BASELINE_ENVS - {"default", "atari"}
    assert {env_id: entries[env_id]["n_steps"] for env_id in chosen} == chosen


@pytest.mark.parametrize("algo", ["offon_paper", "dqn_mc", "dqn_sarsa"])
def test_variants_share_the_dqn_settings(algo: str) -> None:
    """Apart from the target options, each entry is the `dqn` one: the comparison is like for like."""
    for folder in (HYPERPARAMS_DIR, HYPERPARAMS_DIR / "paper"):
        baseline = load(folder / "dqn.yml")
        for env_id, entry in load(folder / f"{algo}.yml").items():
            assert {key: value for key, value in entry.items() if key not in TARGET_KEYS} == baseline[env_id], env_id


def test_choice_is_the_search_winner_on_the_dqn_settings() -> None:
    """`offon_mc_decay`: every entry is the `dqn` one plus the winner's target settings, and nothing else."""
    dqn = load(HYPERPARAMS_DIR / "dqn.yml")
    for env_id, entry in load(HYPERPARAMS_DIR / "offon_mc_decay.yml").items():
        assert {key: entry[key] for key in TARGET_KEYS & set(entry)} == CHOICE_TARGETS, env_id
        assert {key: value for key, value in entry.items() if key not in TARGET_KEYS} == dqn[env_id], env_id


def test_lambda_file_is_the_dqn_settings_with_lambda_targets() -> None:
    """`offon_watkins`: every entry is the `dqn` one plus lambda-return targets (lambda 0.9, Watkins), and nothing else."""
    dqn = load(HYPERPARAMS_DIR / "dqn.yml")
    lambda_targets = {**CHOICE_TARGETS, "mc_initial_prob": 0.9, "mc_final_prob": 0.9, "mc_mixing": "lambda"}
    lambda_targets.update(lambda_block_size=100, lambda_refresh_interval=None)
    entries = load(HYPERPARAMS_DIR / "offon_watkins.yml")
    assert set(entries) == CHOICE_ENVS | MINATAR_ENVS
    for env_id, entry in entries.items():
        assert {key: entry[key] for key in TARGET_KEYS & set(entry)} == lambda_targets, env_id
        assert {key: value for key, value in entry.items() if key not in TARGET_KEYS} == dqn[env_id], env_id


def test_defaults_file_is_offon_watkins_with_the_search_choice() -> None:
    """
    `offon_dqn` (OffOnDQN's defaults): every entry is the `offon_watkins` one with the target settings of the candidate
    that the search chose, `lambda90_peng_r5` (results/search/search_screen.md; its settings in
    benchmarks/search_screen.yml), and nothing else.
    """
    root = Path(__file__).parents[1]
    report = (root / "results" / "search" / "search_screen.md").read_text()
    assert "**Choice: lambda90_peng_r5, " in report
    study = yaml.safe_load((root / "benchmarks" / "search_screen.yml").read_text())
    choice = study["candidates"]["lambda90_peng_r5"]
    overrides = {key: yaml.safe_load(value) for key, value in (item.split(":", 1) for item in choice["hyperparams"])}
    watkins_entries = load(HYPERPARAMS_DIR / "offon_watkins.yml")
    default_entries = load(HYPERPARAMS_DIR / "offon_dqn.yml")
    assert set(default_entries) == set(watkins_entries)
    for env_id, entry in default_entries.items():
        assert entry == {**watkins_entries[env_id], **overrides}, env_id
        assert entry["mc_mixing"] == "lambda", env_id
    assert "`lambda90_peng_r5`" in (HYPERPARAMS_DIR / "offon_dqn.yml").read_text()


def test_dqn_file_copies_the_zoo() -> None:
    zoo = load(Path(rl_zoo3.__file__).parent / "hyperparams" / "dqn.yml")
    ours = load(HYPERPARAMS_DIR / "dqn.yml")
    for env_id in REQUIRED_ENVS & set(zoo):
        assert ours[env_id] == zoo[env_id], env_id
    assert ours["default"] == zoo["default"]


@pytest.mark.parametrize(
    "algo, expected",
    [
        (
            "offon_paper",
            dict(mc_initial_prob=0.99, mc_final_prob=0.01, qlearning_initial_prob=0.99, qlearning_final_prob=0.01),
        ),
        ("dqn_mc", dict(mc_initial_prob=0.99, mc_final_prob=0.01, qlearning_initial_prob=1.0, qlearning_final_prob=1.0)),
        ("dqn_sarsa", dict(mc_initial_prob=0.0, mc_final_prob=0.0, qlearning_initial_prob=0.99, qlearning_final_prob=0.01)),
    ],
)
def test_paper_delta_settings(algo: str, expected: dict[str, float]) -> None:
    for folder, loss in ((HYPERPARAMS_DIR, "huber"), (HYPERPARAMS_DIR / "paper", "mse")):
        for env_id, entry in load(folder / f"{algo}.yml").items():
            assert {key: entry[key] for key in expected} == expected, (folder, env_id)
            assert entry["loss"] == loss


def test_paper_settings() -> None:
    for algo in PAPER_CLASSES:
        for env_id, entry in load(HYPERPARAMS_DIR / "paper" / f"{algo}.yml").items():
            assert entry["policy_kwargs"] == "dict(net_arch=[24, 24], activation_fn=nn.ReLU)"
            assert (entry["gamma"], entry["learning_rate"], entry["batch_size"]) == (0.95, 1e-3, 64)
            assert entry["target_update_interval"] == 300
            assert (entry["exploration_initial_eps"], entry["exploration_final_eps"]) == (1.0, 0.01)
            # Epsilon reaches its floor when the paper's 0.995-per-training-step decay does: 1000 + 919 steps
            assert entry["exploration_fraction"] * entry["n_timesteps"] == pytest.approx(1919, abs=1), (algo, env_id)


def test_resolve_config() -> None:
    assert resolve_config("offon_dqn", None) == str(HYPERPARAMS_DIR / "offon_dqn.yml")
    # A former name reads its new name's file; the paper's configuration has the paper's settings too
    assert resolve_config("offon_lambda_choice", None) == str(HYPERPARAMS_DIR / "offon_dqn.yml")
    assert resolve_config("offon_choice", None) == str(HYPERPARAMS_DIR / "offon_mc_decay.yml")
    assert resolve_config("offon_paper", "paper") == str(HYPERPARAMS_DIR / "paper" / "offon_paper.yml")
    with pytest.raises(FileNotFoundError, match="offon_dqn"):
        resolve_config("offon_dqn", "paper")
    # SB3's DQN reads our copy of the zoo's entries, any other zoo algorithm the zoo's own file
    assert resolve_config("dqn", None) == str(HYPERPARAMS_DIR / "dqn.yml")
    assert resolve_config("ppo", None) is None
    assert resolve_config("dqn_mc", "paper") == str(HYPERPARAMS_DIR / "paper" / "dqn_mc.yml")
    assert resolve_config("dqn_mc", "my/own.yml") == "my/own.yml"
    assert resolve_config("dqn_mc", "my_package.hyperparams") == "my_package.hyperparams"
    assert resolve_config("dqn_mc", "paper/dqn.yml") == "paper/dqn.yml"
    assert resolve_config("dqn_mc", "papers") == "papers"
    with pytest.raises(FileNotFoundError, match="ppo"):
        resolve_config("ppo", "paper")


def build(algo: str, env_id: str, config: Path, log_folder: Path) -> tuple[Any, ExperimentManager]:
    """Build the model of one YAML entry the way ``python -m sb3_offon.train`` does (no training)."""
    args = argparse.Namespace(algo=algo, env=env_id, conf_file=str(config))
    manager = ExperimentManager(args, algo, env_id, str(log_folder), eval_freq=-1, config=str(config), device="cpu")
    results = manager.setup_experiment()
    assert results is not None
    return results[0], manager


@pytest.mark.parametrize("file_set, algo, entry", entries())
def test_every_entry_builds_a_model(tmp_path: Path, file_set: str, algo: str, entry: str) -> None:
    if entry == "atari":
        if algo in ("qrdqn", "qrdqn_nstep", "offon_qrdqn"):
            pytest.skip("the zoo's QR-DQN Atari entry keeps QRDQN's default 1M-frame buffer: 26 GiB to build")
        if not HAS_ALE:
            pytest.skip("ale-py is not installed")
        env_id = "BreakoutNoFrameskip-v4"
    else:
        env_id = UNLISTED_ENV if entry == "default" else entry
    config = HYPERPARAMS_DIR / ("paper" if file_set == "paper" else "") / f"{algo}.yml"
    model, manager = build(algo, env_id, config, tmp_path)
    try:
        assert type(model) is CLASSES[algo]
        values = load(config)[entry]
        for key in TARGET_KEYS & set(values):
            assert getattr(model, key) == values[key], key
        assert model.gamma == values.get("gamma", 0.99)
        if env_id == "CartPoleFallPenalty-v1":
            (callback,) = manager.callbacks
            assert isinstance(callback, StopOnMeanTrainingReward)
            assert (callback.threshold, callback.window, callback.episode_key) == (490, 100, "l")
        elif env_id == "MountainCarGoalBonus-v0":
            (callback,) = manager.callbacks
            assert isinstance(callback, GoalCountCallback)
            assert manager.monitor_kwargs == {"info_keywords": ("goal_reached",)}
        else:
            assert manager.callbacks == []
    finally:
        model.env.close()


@pytest.mark.parametrize("algo", sorted(SAMPLERS))
def test_sampler(algo: str) -> None:
    assert HYPERPARAMS_SAMPLER[algo] is SAMPLERS[algo]
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for _ in range(3):
        trial = study.ask()
        sampled = HYPERPARAMS_SAMPLER[algo](trial, 0, 1, {"using_her_replay_buffer": False, "her_kwargs": {}})
        # What `--trial-id` reloads from a study is what the trial ran with
        assert HYPERPARAMS_CONVERTER[algo](trial.params) == sampled
        assert {"gamma", "learning_rate", "batch_size", "target_update_interval"} <= set(sampled)
        if algo == "dqn_nstep":
            assert sampled["n_steps"] in (3, 5, 10)
            continue
        if algo in ("qrdqn_nstep", "offon_qrdqn"):
            assert 5 <= sampled["policy_kwargs"]["n_quantiles"] <= 200
            if algo == "qrdqn_nstep":
                assert sampled["n_steps"] in (3, 5, 10)
            else:  # lambda and delta2 schedules; no coin flips, no Sarsa target, no loss to choose
                assert {"mc_initial_prob", "mc_final_prob", "qlearning_initial_prob", "mc_truncation"} <= set(sampled)
                assert not {"mc_mixing", "sarsa_target", "loss"} & set(sampled)
            model = ALGOS[algo]("MlpPolicy", "CartPole-v1", device="cpu", **sampled)
            assert model.policy.n_quantiles == sampled["policy_kwargs"]["n_quantiles"]
            study.tell(trial, 0.0)
            continue
        if ALIASES.get(algo, algo) in LAMBDA_CLASSES:
            # lambda and delta2 schedules; mc_mixing stays the YAML's "lambda", and there is no Sarsa target to choose
            assert {"mc_initial_prob", "qlearning_initial_prob", "mc_truncation", "loss"} <= set(sampled)
            assert not {"mc_mixing", "sarsa_target"} & set(sampled)
            model = ALGOS[algo]("MlpPolicy", "CartPole-v1", device="cpu", mc_mixing="lambda", **sampled)
            study.tell(trial, 0.0)
            continue
        assert sampled.get("mc_mixing", "sample") != "lambda", "the coin-flip variants' search space is unchanged"
        assert "loss" in sampled
        has_mc = {"mc_initial_prob", "mc_final_prob", "mc_fraction", "mc_mixing", "mc_truncation"} <= set(sampled)
        has_sarsa = {"qlearning_initial_prob", "qlearning_final_prob", "qlearning_fraction", "sarsa_target"} <= set(sampled)
        # A variant's fixed probability is not sampled
        expected = {"offon_paper": (True, True), "dqn_mc": (True, False), "dqn_sarsa": (False, True)}
        expected["offon_mc_decay"] = expected["dqn_mc"]
        assert (has_mc, has_sarsa) == expected[ALIASES.get(algo, algo)]
        model = ALGOS[algo]("MlpPolicy", "CartPole-v1", device="cpu", **sampled)
        for key in TARGET_KEYS & set(sampled):
            assert getattr(model, key) == sampled[key]
        study.tell(trial, 0.0)
