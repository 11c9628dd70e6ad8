"""The MinAtar games: their registration, the MinAtar paper's network, and the bundled settings for them."""

import importlib
import inspect
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import yaml
from helpers import hide_minatar
from sb3_contrib import QRDQN
from stable_baselines3 import DQN
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import SubprocVecEnv
from torch import nn

import sb3_offon.minatar_envs
from sb3_offon import MinAtarCNN, OffOnDQN
from sb3_offon.minatar_envs import MINATAR_GAMES, MINATAR_MAX_EPISODE_STEPS, minatar_ids, register_minatar_envs
from sb3_offon.offon_dqn.offon_dqn import OFFON_PARAMETERS
from sb3_offon.zoo import HYPERPARAMS_DIR

pytest.importorskip("minatar", reason="the 'minatar' extra is not installed")

# Each game's channels and minimal action set, as MinAtar 1.0.15 defines them
CHANNELS = {"Asterix": 4, "Breakout": 4, "Freeway": 7, "Seaquest": 10, "SpaceInvaders": 6}
MINIMAL_ACTIONS = {"Asterix": 5, "Breakout": 3, "Freeway": 3, "Seaquest": 6, "SpaceInvaders": 4}
MINATAR_KWARGS = dict(features_extractor_class=MinAtarCNN, net_arch=[])
# The algorithms whose YAML files have the MinAtar entries, and what each may add to DQN's settings there
MINATAR_ALGOS = ("dqn", "dqn_nstep", "qrdqn", "offon_paper", "offon_watkins", "offon_dqn")


@pytest.mark.parametrize("name", sorted(MINATAR_GAMES))
def test_registration(name: str) -> None:
    for version, n_actions in (("v0", 6), ("v1", MINIMAL_ACTIONS[name])):
        env = gym.make(f"MinAtar/{name}-{version}")
        assert env.spec is not None and env.spec.max_episode_steps == MINATAR_MAX_EPISODE_STEPS
        assert env.observation_space.shape == (10, 10, CHANNELS[name]) and env.observation_space.dtype == np.bool_
        assert env.action_space == gym.spaces.Discrete(n_actions)
        obs, _ = env.reset(seed=0)
        assert obs.shape == (10, 10, CHANNELS[name]) and obs.dtype == np.bool_ and obs.any()
        env.close()


def test_registered_once_and_without_a_wrong_deprecation_warning() -> None:
    assert minatar_ids() == [f"MinAtar/{name}-{version}" for name in MINATAR_GAMES for version in ("v0", "v1")]
    assert all(env_id in gym.registry for env_id in minatar_ids())
    with warnings.catch_warnings():
        # A second registration would warn that it overrides; a -v0 would be called "out of date" next to its -v1
        warnings.simplefilter("error")
        register_minatar_envs()
        importlib.reload(sb3_offon.minatar_envs)
        gym.make("MinAtar/Breakout-v0").close()


def test_time_limit_ends_a_game_that_never_ends() -> None:
    """A Seaquest submarine that never dives plays forever: the time limit truncates its episode (not a termination)."""
    env = gym.make("MinAtar/Seaquest-v0", sticky_action_prob=0.0)
    env.reset(seed=0)
    flags = [env.step(0)[2:4] for _ in range(MINATAR_MAX_EPISODE_STEPS)]
    assert flags == [(False, False)] * (MINATAR_MAX_EPISODE_STEPS - 1) + [(False, True)]


def test_minimal_action_set_maps_to_the_game_actions() -> None:
    """-v1's action i is the game's i-th minimal action: Breakout's are no-op, left and right (0, 1, 3)."""
    env = gym.make("MinAtar/Breakout-v1", sticky_action_prob=0.0)
    assert env.unwrapped.action_set == [0, 1, 3]


def test_missing_extra_names_it(monkeypatch: pytest.MonkeyPatch) -> None:
    hide_minatar(monkeypatch)
    with pytest.raises(ModuleNotFoundError, match=r"'minatar' dependencies.*pip install -e \"\.\[minatar\]\""):
        gym.make("MinAtar/Breakout-v0")


def test_subprocess_workers_find_the_ids_with_the_module() -> None:
    env = make_vec_env("sb3_offon:MinAtar/Freeway-v1", n_envs=2, vec_env_cls=SubprocVecEnv, seed=0)
    try:
        assert env.observation_space.shape == (10, 10, 7) and env.action_space.n == 3
        obs = env.reset()
        assert obs.shape == (2, 10, 10, 7)
        env.step(np.array([1, 2]))
    finally:
        env.close()


def test_extractor_layers() -> None:
    space = gym.make("MinAtar/Seaquest-v0").observation_space
    extractor = MinAtarCNN(space)
    conv, relu, flatten = extractor.cnn
    assert (conv.in_channels, conv.out_channels, conv.kernel_size) == (10, 16, (3, 3))
    assert (conv.stride, conv.padding) == ((1, 1), (0, 0))
    assert isinstance(relu, nn.ReLU) and isinstance(flatten, nn.Flatten)
    linear, relu = extractor.linear
    assert (linear.in_features, linear.out_features) == (1024, 128) and isinstance(relu, nn.ReLU)
    assert extractor.features_dim == 128


def test_extractor_forward_on_a_real_observation() -> None:
    """The features of a Breakout frame, against the paper's computation written out with torch's functions."""
    env = gym.make("MinAtar/Breakout-v0")
    obs, _ = env.reset(seed=3)
    extractor = MinAtarCNN(env.observation_space)
    x = th.as_tensor(obs[None]).float()
    conv, linear = extractor.cnn[0], extractor.linear[0]
    # The grid (10, 10, C) as channels (C, 10, 10); MinAtar's dqn.py does the same with permute(2, 0, 1)
    expected = th.relu(th.nn.functional.conv2d(x.permute(0, 3, 1, 2), conv.weight, conv.bias))
    expected = th.relu(expected.reshape(1, -1) @ linear.weight.T + linear.bias)
    with th.no_grad():
        features = extractor(th.as_tensor(obs[None]))  # a bool tensor, as obs_as_tensor gives it
    th.testing.assert_close(features, expected)
    # Channels first takes the same observation transposed to the same features
    first = MinAtarCNN(gym.spaces.Box(0, 1, (4, 10, 10), dtype=bool), channels_last=False)
    first.load_state_dict(extractor.state_dict())
    with th.no_grad():
        th.testing.assert_close(first(th.as_tensor(obs[None]).permute(0, 3, 1, 2)), features)


def test_extractor_rejects_other_spaces() -> None:
    with pytest.raises(ValueError, match="`observation_space` must be a Box of three dimensions"):
        MinAtarCNN(gym.spaces.Box(0, 1, (10, 10)))
    with pytest.raises(ValueError, match="at least 3 x 3"):
        MinAtarCNN(gym.spaces.Box(0, 1, (2, 2, 4)))


def extractors(model) -> list[type]:
    """The features extractors' classes of the policy's networks (DQN's q_net and q_net_target, QR-DQN's quantile_net...)."""
    return [type(module.features_extractor) for module in model.policy.children()]


@pytest.mark.parametrize("algo_class", [OffOnDQN, DQN, QRDQN])
def test_each_algorithm_learns_saves_and_loads(tmp_path: Path, algo_class: type) -> None:
    env = make_vec_env("MinAtar/Breakout-v1", n_envs=2, seed=0)
    model = algo_class(
        "CnnPolicy", env, policy_kwargs=MINATAR_KWARGS, buffer_size=500, learning_starts=50, batch_size=8, seed=0, device="cpu"
    )
    model.learn(300)
    assert extractors(model) == [MinAtarCNN, MinAtarCNN]  # the online and the target network
    obs = env.reset()
    actions, _ = model.predict(obs, deterministic=True)
    model.save(tmp_path / "model")
    loaded = algo_class.load(tmp_path / "model", device="cpu")
    assert extractors(loaded) == [MinAtarCNN, MinAtarCNN]
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], actions)
    env.close()


def test_optimize_memory_usage(tmp_path: Path) -> None:
    model = OffOnDQN(
        "CnnPolicy",
        "MinAtar/Asterix-v0",
        policy_kwargs=MINATAR_KWARGS,
        buffer_size=200,
        learning_starts=50,
        optimize_memory_usage=True,
        replay_buffer_kwargs=dict(handle_timeout_termination=False),
        seed=0,
        device="cpu",
    )
    model.learn(400)  # the ring buffer wraps
    # SB3's memory-saving layout: no array of next observations, read from the next slot instead
    assert model.replay_buffer.full and not hasattr(model.replay_buffer, "next_observations")
    assert model.replay_buffer.observations.dtype == np.bool_


def load(algo: str) -> dict:
    with open(HYPERPARAMS_DIR / f"{algo}.yml") as file:
        return yaml.safe_load(file)


def test_yaml_entries_are_the_minatar_paper_settings_for_every_algorithm() -> None:
    dqn = load("dqn")
    entry = dqn["MinAtar/Breakout-v0"]
    assert entry == {
        "n_timesteps": 1e6,
        "policy": "CnnPolicy",
        "buffer_size": 100_000,
        "batch_size": 32,
        "learning_starts": 5000,
        "target_update_interval": 1000,
        "train_freq": 4,
        "gradient_steps": 1,
        "exploration_initial_eps": 1.0,
        "exploration_final_eps": 0.1,
        "exploration_fraction": 0.1,
        "gamma": 0.99,
        "learning_rate": 2.5e-4,
        "policy_kwargs": "dict(features_extractor_class=MinAtarCNN, net_arch=[], optimizer_class=th.optim.RMSprop, "
        "optimizer_kwargs=dict(alpha=0.95, eps=0.01, centered=True))",
    }
    # epsilon reaches 0.1 after the MinAtar paper's first 100,000 steps
    assert entry["exploration_fraction"] * entry["n_timesteps"] == 100_000
    defaults = inspect.signature(OffOnDQN.__init__).parameters
    targets = {name: defaults[name].default for name in OFFON_PARAMETERS}
    for algo in MINATAR_ALGOS:
        entries = load(algo)
        assert {env_id for env_id in entries if env_id.startswith("MinAtar/")} == set(minatar_ids()), algo
        for env_id in minatar_ids():
            extra = {key: value for key, value in entries[env_id].items() if key not in entry}
            assert {key: entries[env_id][key] for key in entry} == entry, (algo, env_id)
            if algo == "dqn_nstep":
                assert extra == {"n_steps": 3}
            elif algo == "offon_dqn":
                # OffOnDQN's targets as its constructor defaults have them
                assert extra and all(extra[key] == targets[key] for key in extra), extra
            elif algo in ("dqn", "qrdqn"):
                assert extra == {}, algo


def test_yaml_entry_builds_the_paper_network_and_optimizer(tmp_path: Path) -> None:
    from test_hyperparams import build

    # The MinAtar head-to-head runs OffOnDQN's defaults under their former name: it reads offon_dqn.yml
    model, _ = build("offon_lambda_choice", "MinAtar/Breakout-v0", HYPERPARAMS_DIR / "offon_dqn.yml", tmp_path)
    try:
        assert isinstance(model.q_net.features_extractor, MinAtarCNN)
        assert [type(layer) for layer in model.q_net.q_net] == [nn.Linear]
        optimizer = model.policy.optimizer
        assert isinstance(optimizer, th.optim.RMSprop)
        group = optimizer.param_groups[0]
        assert (group["lr"], group["alpha"], group["eps"], group["centered"]) == (2.5e-4, 0.95, 0.01, True)
        assert model.exploration_final_eps == 0.1 and model.learning_starts == 5000
    finally:
        model.env.close()
