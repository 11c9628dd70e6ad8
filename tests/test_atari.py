"""Atari: DER's network, the evaluation games and policy of the Atari 100k protocol, and its settings on the command line."""

import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import yaml
from helpers import interrupt_after_checkpoint
from stable_baselines3 import DQN
from stable_baselines3.common.envs import FakeImageEnv, IdentityEnv

from sb3_offon import DataEfficientCNN, OffOnDQN
from sb3_offon.atari import AtariEvaluationWrapper, FireAfterLifeLossEnv, ale_v5_kwargs, looks_like_atari
from sb3_offon.evaluation import FINAL_EVALUATION_FILE, EpsilonGreedyPredictor
from sb3_offon.resume import Checkpoint
from sb3_offon.train import main
from sb3_offon.zoo import resolve_config

pytest.importorskip("ale_py")
pytest.importorskip("cv2")


# --- DER's network --------------------------------------------------------------------------------------------------


def test_data_efficient_cnn_shapes_on_atari_frames():
    space = gym.spaces.Box(0, 255, (4, 84, 84), np.uint8)
    extractor = DataEfficientCNN(space)
    # 84 -> 16 -> 3 after two 5 x 5 convolutions of stride 5: 64 x 3 x 3 = 576 values into 256 units
    assert extractor.linear[0].in_features == 576 and extractor.features_dim == 256
    assert extractor(th.rand(2, 4, 84, 84)).shape == (2, 256)
    assert [layer.stride for layer in extractor.cnn if isinstance(layer, th.nn.Conv2d)] == [(5, 5), (5, 5)]


@pytest.mark.parametrize(
    "space, match",
    [
        (gym.spaces.Box(0, 255, (4, 20, 84), np.uint8), "at least 25 x 25"),
        (gym.spaces.Box(0, 1, (10,), np.float32), "three dimensions"),
        (gym.spaces.Discrete(3), "three dimensions"),
    ],
)
def test_data_efficient_cnn_refuses_what_it_cannot_take(space, match):
    with pytest.raises(ValueError, match=match):
        DataEfficientCNN(space)


def test_offon_dqn_trains_with_the_data_efficient_network():
    env = FakeImageEnv(screen_height=84, screen_width=84, n_channels=4, discrete=True)
    model = OffOnDQN(
        "CnnPolicy",
        env,
        buffer_size=500,
        learning_starts=100,
        target_update_interval=50,
        policy_kwargs=dict(features_extractor_class=DataEfficientCNN, net_arch=[]),
        seed=0,
    )
    before = [parameter.detach().clone() for parameter in model.q_net.parameters()]
    model.learn(300)
    assert isinstance(model.q_net.features_extractor, DataEfficientCNN)
    assert all(not th.equal(old, new) for old, new in zip(before, model.q_net.parameters(), strict=True))


# --- the ALE's ids and the evaluation games --------------------------------------------------------------------------


def test_ale_ids_are_registered_on_import():
    assert "BreakoutNoFrameskip-v4" in gym.registry and "ALE/Breakout-v5" in gym.registry
    assert looks_like_atari("ALE/Pong-v5") and looks_like_atari("PongNoFrameskip-v4") and not looks_like_atari("CartPole-v1")


def test_an_ale_v5_id_gets_the_noframeskip_arguments_once():
    kwargs, line = ale_v5_kwargs("ALE/Pong-v5", {})
    assert kwargs == {"frameskip": 1, "repeat_action_probability": 0.0}
    assert line is not None and "ALE/Pong-v5" in line and "frameskip=1" in line
    kwargs, line = ale_v5_kwargs("ALE/Pong-v5", {"frameskip": 1, "repeat_action_probability": 0.25})
    assert kwargs == {"frameskip": 1, "repeat_action_probability": 0.25} and line is None, "the user's are kept"
    assert ale_v5_kwargs("PongNoFrameskip-v4", {}) == ({}, None)


class LivesEnv(gym.Env):
    """A game with three lives: each action is recorded; a life is lost at steps 2 and 6, the game ends with the third."""

    observation_space = gym.spaces.Discrete(100)
    action_space = gym.spaces.Discrete(4)

    def __init__(self) -> None:
        self.actions: list[int] = []
        self.ale = self  # what FireAfterLifeLossEnv reads lives from (env.unwrapped.ale.lives())
        self.n_lives = 3

    def lives(self) -> int:
        return self.n_lives

    def reset(self, **kwargs: Any) -> tuple[int, dict]:
        self.actions, self.n_lives = [], 3
        return 0, {}

    def step(self, action: int) -> tuple[int, float, bool, bool, dict]:
        self.actions.append(int(action))
        if len(self.actions) in (2, 6, 10):
            self.n_lives -= 1
        return len(self.actions), 1.0, self.n_lives == 0, False, {}


def test_a_life_lost_is_followed_by_the_steps_a_training_episode_starts_with():
    env = FireAfterLifeLossEnv(LivesEnv())
    env.reset()
    assert env.step(3)[:3] == (1, 1.0, False)
    # The second step loses a life: no-op, FIRE and the action after FIRE follow, their rewards added
    obs, reward, terminated, _, _ = env.step(3)
    assert (obs, reward, terminated) == (5, 4.0, False) and env.unwrapped.actions == [3, 3, 0, 1, 2]
    env.step(3)  # step 6 loses the second life
    assert env.unwrapped.actions[5:] == [3, 0, 1, 2]
    # The last life lost ends the game: nothing follows it
    _, reward, terminated, _, _ = env.step(3)
    assert terminated and reward == 1.0 and len(env.unwrapped.actions) == 10


def test_an_evaluation_game_goes_on_after_a_life_lost_and_keeps_its_rewards():
    env = AtariEvaluationWrapper(gym.make("BreakoutNoFrameskip-v4"))
    obs, _ = env.reset(seed=0)
    assert obs.shape == (84, 84, 1)
    lives, lost_and_going_on = env.unwrapped.ale.lives(), False
    for _ in range(3_000):
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            break
        lost_and_going_on |= env.unwrapped.ale.lives() < lives
    assert lost_and_going_on, "a life was lost and the episode went on"
    assert terminated and env.unwrapped.ale.lives() == 0, "the episode ended with the game"


# --- the evaluation policy -------------------------------------------------------------------------------------------


def test_epsilon_greedy_predictor():
    model = DQN("MlpPolicy", IdentityEnv(10), learning_starts=0, seed=0)
    observations = np.arange(10)
    greedy, _ = model.predict(observations, deterministic=True)
    np.testing.assert_array_equal(EpsilonGreedyPredictor(model, 0.0, seed=0).predict(observations)[0], greedy)
    drawn = np.concatenate([EpsilonGreedyPredictor(model, 1.0, seed=seed).predict(observations)[0] for seed in range(20)])
    assert set(drawn.tolist()) == set(range(10)), "every action drawn at rate 1"
    actions = [EpsilonGreedyPredictor(model, 0.5, seed=3).predict(observations)[0] for _ in range(2)]
    np.testing.assert_array_equal(*actions)  # seeded
    predictor = EpsilonGreedyPredictor(model, 0.001)
    assert predictor.num_timesteps == model.num_timesteps and predictor.policy is model.policy
    with pytest.raises(ValueError, match="`exploration_rate`"):
        EpsilonGreedyPredictor(model, 1.5)


# --- the atari100k settings on the command line ---------------------------------------------------------------------

SHORT = [
    "--env", "BreakoutNoFrameskip-v4", "-conf", "atari100k", "--seed", "0", "-n", "400", "--eval-freq", "200",
    "--eval-episodes", "1", "--hyperparams", "learning_starts:100", "buffer_size:1000", "target_update_interval:100",
    "final_eval_episodes:2",
]  # fmt: skip


def train(monkeypatch: pytest.MonkeyPatch, folder: Path, algo: str, *extra: str) -> Path:
    monkeypatch.setattr(sys, "argv", ["sb3_offon.train", "--algo", algo, *SHORT, "-f", str(folder), *extra])
    main()
    (run,) = (folder / algo).iterdir()
    return run


@pytest.mark.parametrize("algo", ["dqn", "dqn_nstep", "offon_dqn", "qrdqn", "qrdqn_nstep", "offon_qrdqn"])
def test_every_atari100k_file_is_the_same_protocol(algo):
    protocol = yaml.safe_load(Path(resolve_config("dqn", "atari100k")).read_text())["atari"]
    entry = yaml.safe_load(Path(resolve_config(algo, "atari100k")).read_text())["atari"]
    # policy_kwargs: the QR-DQN files name Adam (test_every_atari100k_file_builds_its_model checks the optimizer)
    own = {"optimize_memory_usage", "replay_buffer_kwargs", "n_steps", "policy_kwargs"}
    own |= {key for key in entry if key.startswith(("mc_", "q"))}
    own |= {"loss", "lambda_block_size", "lambda_refresh_interval"}
    assert {key: value for key, value in entry.items() if key not in own} == {
        key: value for key, value in protocol.items() if key not in own
    }
    assert entry["n_timesteps"] == 100_000 and entry["train_freq"] == 1 and entry["learning_starts"] == 1600
    assert entry["eval_exploration_rate"] == 0.001 and entry["final_eval_episodes"] == 100
    assert entry.get("n_steps", 1) == (10 if algo.endswith("nstep") else 1)


@pytest.mark.slow
def test_an_atari100k_run_evaluates_whole_games_and_scores_them_after_training(tmp_path, monkeypatch):
    run = train(monkeypatch, tmp_path, "offon_dqn")
    evaluations = np.load(run / "evaluations.npz")
    np.testing.assert_array_equal(evaluations["timesteps"], [200, 400])
    final = np.load(run / FINAL_EVALUATION_FILE)
    assert final["results"].shape == (2,) and int(final["timesteps"]) == 400 and float(final["exploration_rate"]) == 0.001
    # Whole games: at least the five lives' worth of frames of a Breakout game (a life lost at once takes ~100 frames)
    assert (final["ep_lengths"] > 500).all()
    config = yaml.unsafe_load((run / "BreakoutNoFrameskip-v4" / "config.yml").read_text())  # the zoo's OrderedDict
    assert dict(config)["eval_env_wrapper"] == "sb3_offon.atari.AtariEvaluationWrapper"
    model = OffOnDQN.load(run / "BreakoutNoFrameskip-v4.zip")
    assert isinstance(model.q_net.features_extractor, DataEfficientCNN) and model.optimize_memory_usage


@pytest.mark.slow
def test_an_interrupted_atari100k_run_resumes_with_its_replay_buffer(tmp_path, monkeypatch):
    with monkeypatch.context() as patch:
        interrupt_after_checkpoint(patch, 200)
        cut = train(patch, tmp_path / "cut", "offon_dqn", "--checkpoint-freq", "200")
    assert not (cut / FINAL_EVALUATION_FILE).exists(), "no final score for a run cut short"
    checkpoint = Checkpoint.latest(cut / "checkpoint")
    assert checkpoint is not None and checkpoint.num_timesteps == 200
    assert (checkpoint.folder / "replay_buffer.pkl").is_file()
    resumed = train(monkeypatch, tmp_path / "resumed", "offon_dqn", "--resume", str(cut))
    np.testing.assert_array_equal(np.load(resumed / "evaluations.npz")["timesteps"], [200, 400])
    assert np.load(resumed / FINAL_EVALUATION_FILE)["results"].shape == (2,)
    assert OffOnDQN.load(resumed / "BreakoutNoFrameskip-v4.zip").num_timesteps == 400


def test_an_ale_v5_id_on_the_command_line_is_said_in_one_line(tmp_path, monkeypatch, capsys):
    argv = ["--algo", "dqn", *SHORT[2:]]
    argv[argv.index("400")] = "50"
    argv[argv.index("200")] = "50"
    monkeypatch.setattr(sys, "argv", ["sb3_offon.train", "--env", "ALE/Breakout-v5", *argv, "-f", str(tmp_path)])
    main()
    lines = [line for line in capsys.readouterr().err.splitlines() if "ALE/Breakout-v5 under AtariWrapper" in line]
    assert len(lines) == 1 and "frameskip=1" in lines[0]
    (run,) = (tmp_path / "dqn").iterdir()
    assert (run / FINAL_EVALUATION_FILE).is_file()


@pytest.mark.parametrize("algo", ["dqn", "dqn_nstep", "offon_dqn", "qrdqn", "qrdqn_nstep", "offon_qrdqn"])
def test_every_atari100k_file_builds_its_model(tmp_path, algo):
    import argparse

    from rl_zoo3.utils import ALGOS

    from sb3_offon.zoo import OffOnExperimentManager, register

    register()
    config = resolve_config(algo, "atari100k")
    args = argparse.Namespace(algo=algo, env="BreakoutNoFrameskip-v4", conf_file=config)
    manager = OffOnExperimentManager(args, algo, "BreakoutNoFrameskip-v4", str(tmp_path), eval_freq=-1, config=config)
    model, _ = manager.setup_experiment()
    try:
        assert isinstance(model, ALGOS[algo])
        network = model.policy.quantile_net if hasattr(model.policy, "quantile_net") else model.policy.q_net
        assert isinstance(network.features_extractor, DataEfficientCNN)
        assert isinstance(model.policy.optimizer, th.optim.Adam) and model.policy.optimizer.defaults["eps"] == 1.5e-4
        assert model.learning_starts == 1600 and model.policy.optimizer.defaults["lr"] == 1e-4
        assert model.replay_buffer.buffer_size == 100_000
        assert model.optimize_memory_usage == (not algo.endswith("nstep"))
        assert manager.eval_exploration_rate == 0.001 and manager.final_eval_episodes == 100
    finally:
        model.env.close()
