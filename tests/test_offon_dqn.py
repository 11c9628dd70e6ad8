"""OffOnDQN: schedules, bit-identity with DQN, VecEnv bookkeeping, save/load, observation types, bad input, logging."""

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from helpers import assert_same_parameters
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.envs import FakeImageEnv, IdentityEnv, SimpleMultiObsEnv
from stable_baselines3.common.logger import KVWriter, Logger
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from sb3_offon import PAPER_TARGETS, OffOnDictReplayBuffer, OffOnDQN, OffOnNStepReplayBuffer, OffOnReplayBuffer
from sb3_offon.common.buffers import discounted_returns

SMALL = dict(
    learning_starts=100,
    buffer_size=2000,
    batch_size=32,
    train_freq=4,
    target_update_interval=100,
    policy_kwargs=dict(net_arch=[16]),
    device="cpu",
)


def paper_offon_dqn(*args, **kwargs) -> OffOnDQN:
    """
    OffOnDQN with the paper's coin-flip targets (``PAPER_TARGETS``), which this file tests, unless ``kwargs`` say
    otherwise: OffOnDQN's own defaults are lambda-returns (tests/test_lambda_returns.py, tests/test_presets.py).
    """
    return OffOnDQN(*args, **{**PAPER_TARGETS, **kwargs})


# SB3's DQN, bit for bit: the coin-flip mode with delta1 = 0 and delta2 = 1
Q_ONLY = dict(mc_mixing="sample", mc_initial_prob=0.0, mc_final_prob=0.0, qlearning_initial_prob=1.0, qlearning_final_prob=1.0)


def constant_probs(mc: float, qlearning: float) -> dict:
    return dict(mc_initial_prob=mc, mc_final_prob=mc, qlearning_initial_prob=qlearning, qlearning_final_prob=qlearning)


def max_target_q(model: OffOnDQN, observation: np.ndarray) -> float:
    """max_a Q_target(s, a) of one observation as the buffer stores it: the bootstrap of a cut-off episode."""
    with th.no_grad():
        return model.q_net_target(th.as_tensor(observation[None])).max().item()


# --- schedules ---------------------------------------------------------------------------------------------------


def test_schedules_decay_linearly_then_stay():
    model = paper_offon_dqn(
        "MlpPolicy",
        "CartPole-v1",
        mc_initial_prob=0.9,
        mc_final_prob=0.1,
        mc_fraction=0.5,
        qlearning_initial_prob=0.2,
        qlearning_final_prob=0.8,
        qlearning_fraction=1.0,
        **SMALL,
    )
    assert model.mc_schedule(1.0) == pytest.approx(0.9)
    assert model.mc_schedule(0.75) == pytest.approx(0.5)
    assert model.mc_schedule(0.5) == pytest.approx(0.1)
    assert model.mc_schedule(0.1) == pytest.approx(0.1)
    assert model.qlearning_schedule(0.5) == pytest.approx(0.5)
    assert model.qlearning_schedule(0.0) == pytest.approx(0.8)
    model.learn(1000)
    # The last training call happened near the end: delta1 is at its final value, delta2 close to it
    assert model.mc_prob == pytest.approx(0.1)
    assert model.qlearning_prob == pytest.approx(0.8, abs=0.01)


# --- bit-identity with DQN ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "extra",
    [
        {},
        {"n_steps": 3},
        {"n_envs": 1},
        {"optimize_memory_usage": True, "replay_buffer_kwargs": {"handle_timeout_termination": False}},
        # Many gradient steps per call, on a buffer that fills and wraps around: one gather for all of a call's steps
        # (15 to 30 s each on a busy 2-core machine: the slow set)
        pytest.param({"n_envs": 1, "gradient_steps": 24, "buffer_size": 300}, marks=pytest.mark.slow),
        pytest.param(
            {
                "optimize_memory_usage": True,
                "replay_buffer_kwargs": {"handle_timeout_termination": False},
                "n_envs": 1,
                "gradient_steps": 24,
                "buffer_size": 300,
            },
            marks=pytest.mark.slow,
        ),
    ],
    ids=["1-step", "3-step", "one-env", "optimize-memory", "one-env-many-steps", "optimize-memory-many-steps"],
)
def test_bit_identical_to_dqn_with_qlearning_only(extra):
    def train(algo, **kwargs):
        settings = {**SMALL, "gradient_steps": 2, **extra}
        env = make_vec_env("CartPole-v1", n_envs=settings.pop("n_envs", 2), seed=5)
        return algo("MlpPolicy", env, seed=5, **settings, **kwargs).learn(800)

    ours, theirs = train(OffOnDQN, **Q_ONLY), train(DQN)
    assert ours.num_timesteps == theirs.num_timesteps
    assert_same_parameters(ours, theirs)
    # The Off-On bookkeeping ran all the same
    assert not np.isnan(ours.replay_buffer.mc_returns).all()


# --- end-to-end bookkeeping with VecEnvs -------------------------------------------------------------------------


def test_returns_in_training_match_rewards_and_truncation_bootstrap():
    """Two envs with different time limits: every finished episode's returns follow G_t = r_t + gamma * G_{t+1}."""
    env = DummyVecEnv([lambda limit=limit: Monitor(gym.make("CartPole-v1", max_episode_steps=limit)) for limit in (9, 40)])
    env.seed(1)
    # No gradient step before the end (learning_starts), so the target network is the same throughout
    model = paper_offon_dqn(
        "MlpPolicy", env, gamma=0.9, seed=1, exploration_final_eps=1.0, **{**SMALL, "learning_starts": 10_000}
    )
    model.learn(400)
    buffer = model.replay_buffer
    n = buffer.pos
    for env_index in range(2):
        rewards, dones = buffer.rewards[:n, env_index], buffer.dones[:n, env_index].astype(bool)
        timeouts = buffer.timeouts[:n, env_index].astype(bool)
        ends = np.flatnonzero(dones)
        assert len(ends) > 3
        start = 0
        for end in ends:
            tail = 0.0
            if timeouts[end]:
                tail = max_target_q(model, buffer.next_observations[end, env_index])
            expected = discounted_returns(rewards[start : end + 1], 0.9, tail)
            np.testing.assert_allclose(buffer.mc_returns[start : end + 1, env_index], expected, rtol=1e-5)
            next_actions = buffer.next_actions[start : end + 1, env_index]
            np.testing.assert_array_equal(next_actions[:-1], buffer.actions[start + 1 : end + 1, env_index, 0])
            assert next_actions[-1] == -1
            start = end + 1
    assert buffer.timeouts[:n, 0].any() and (buffer.dones[:n, 1] * (1 - buffer.timeouts[:n, 1])).any(), (
        "both truncations and terminations occurred"
    )


def test_reward_normalisation_scales_returns_like_rewards():
    """The buffer keeps raw rewards and raw returns; VecNormalize's reward scale is applied to both at sampling."""
    venv = VecNormalize(DummyVecEnv([lambda: gym.make("CartPole-v1", max_episode_steps=15)]), norm_obs=False, gamma=0.9)
    model = paper_offon_dqn(
        "MlpPolicy", venv, gamma=0.9, seed=0, exploration_final_eps=1.0, **{**SMALL, "learning_starts": 10_000}
    )

    def reward_scale() -> float:
        """What VecNormalize divides rewards by now."""
        return float(np.sqrt(venv.ret_rms.var + venv.epsilon))

    scales_by_step = []  # the reward scale after each env step: the one the buffer's add() of that step sees

    def record_scale(_locals, _globals) -> bool:
        scales_by_step.append(reward_scale())
        return True

    model.learn(300, callback=record_scale)
    buffer = model.replay_buffer
    scale = reward_scale()
    assert abs(scale - 1.0) > 0.1, "a scale of 1 would not test anything"
    # Raw units in the buffer: a terminated episode's returns are those of its raw rewards (CartPole: 1 per step)
    ends = np.flatnonzero(buffer.dones[: buffer.pos, 0])
    terminated = [i for i in range(1, len(ends)) if not buffer.timeouts[ends[i], 0]]
    assert terminated
    start, end = ends[terminated[0] - 1] + 1, ends[terminated[0]]
    expected = discounted_returns(buffer.rewards[start : end + 1, 0], 0.9)
    np.testing.assert_allclose(buffer.mc_returns[start : end + 1, 0], expected, rtol=1e-5)
    # Samples: rewards and returns divided by the same scale
    slots = np.arange(start, end + 1)
    samples = buffer._get_samples(slots, env=venv)
    np.testing.assert_allclose(samples.rewards.numpy()[:, 0], buffer.rewards[slots, 0] / scale, rtol=1e-5)
    np.testing.assert_allclose(samples.mc_returns.numpy()[:, 0], buffer.mc_returns[slots, 0] / scale, rtol=1e-5)
    # A truncation's bootstrap, max_a Q_target (learnt from normalised rewards), enters the raw return times the scale
    # of the moment the episode ended (no gradient step: the target network is the same throughout)
    final_obs = buffer.next_observations[:3, 0]
    with th.no_grad():
        q_values = model.q_net_target(th.as_tensor(final_obs)).max(dim=1).values.numpy()
    np.testing.assert_allclose(model._target_state_values(final_obs), q_values * scale, rtol=1e-5)
    truncated = [i for i in range(1, len(ends)) if buffer.timeouts[ends[i], 0]]
    assert len(truncated) >= 3 and len(scales_by_step) == buffer.pos
    for i in truncated:
        start, end = ends[i - 1] + 1, ends[i]
        tail = max_target_q(model, buffer.next_observations[end, 0]) * scales_by_step[end]
        expected = discounted_returns(buffer.rewards[start : end + 1, 0], 0.9, tail)
        np.testing.assert_allclose(buffer.mc_returns[start : end + 1, 0], expected, rtol=1e-5)


def test_set_random_seed_reseeds_the_target_draws():
    model = paper_offon_dqn("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    model.learn(300)
    model.set_random_seed(5)
    assert model.target_rng.bit_generator.state == np.random.default_rng(5).bit_generator.state


def test_terminal_truncation_mode_sets_no_value_function():
    model = paper_offon_dqn("MlpPolicy", "CartPole-v1", mc_truncation="terminal", **SMALL)
    assert model.replay_buffer.truncation_value_fn is None
    assert paper_offon_dqn("MlpPolicy", "CartPole-v1", **SMALL).replay_buffer.truncation_value_fn is not None


def test_drop_truncation_mode_sets_the_buffer_and_survives_a_buffer_reload(tmp_path):
    model = paper_offon_dqn("MlpPolicy", "CartPole-v1", mc_truncation="drop", **SMALL)
    assert model.replay_buffer.drop_truncated_returns is True
    assert model.replay_buffer.truncation_value_fn is None
    assert paper_offon_dqn("MlpPolicy", "CartPole-v1", **SMALL).replay_buffer.drop_truncated_returns is False
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    other = paper_offon_dqn("MlpPolicy", "CartPole-v1", **SMALL)
    other.load_replay_buffer(tmp_path / "buffer.pkl")
    assert other.replay_buffer.drop_truncated_returns is False, "the loading model's mc_truncation decides"


def test_drop_truncation_keeps_only_returns_of_terminated_episodes():
    # CartPole cut at 20 steps: terminated episodes (the pole fell) get returns, truncated ones (20 steps) none
    env = gym.make("CartPole-v1", max_episode_steps=20)
    model = paper_offon_dqn("MlpPolicy", env, mc_truncation="drop", gamma=0.9, seed=1, **SMALL)
    model.learn(400)
    buffer = model.replay_buffer
    ends = np.flatnonzero(buffer.dones[: buffer.pos, 0])
    kinds = {bool(buffer.timeouts[end, 0]) for end in ends}
    assert kinds == {True, False}, "the run must hold both kinds of episode end"
    start = 0
    for end in ends:
        returns = buffer.mc_returns[start : end + 1, 0]
        if buffer.timeouts[end, 0]:
            assert np.isnan(returns).all()
        else:
            np.testing.assert_allclose(returns, discounted_returns(buffer.rewards[start : end + 1, 0], 0.9), rtol=1e-5)
        start = end + 1


# --- save / load -------------------------------------------------------------------------------------------------


def test_save_load_model_buffer_and_resume(tmp_path):
    kwargs = dict(constant_probs(0.4, 0.6), mc_mixing="convex", sarsa_target="expected", mc_truncation="terminal", loss="mse")
    model = paper_offon_dqn("MlpPolicy", "CartPole-v1", seed=3, mc_fraction=0.5, qlearning_fraction=0.7, **kwargs, **SMALL)
    model.learn(600)
    model.save(tmp_path / "model.zip")
    model.save_replay_buffer(tmp_path / "buffer.pkl")

    loaded = OffOnDQN.load(tmp_path / "model.zip", env=gym.make("CartPole-v1"), device="cpu")
    for name, value in dict(kwargs, mc_fraction=0.5, qlearning_fraction=0.7).items():
        assert getattr(loaded, name) == value, name
    assert loaded.target_rng.bit_generator.state == model.target_rng.bit_generator.state, "draws resume where they were"
    for ours, theirs in zip(model.policy.state_dict().values(), loaded.policy.state_dict().values(), strict=True):
        assert th.equal(ours, theirs)

    # truncate_last_traj=False: the buffer exactly as it was saved, its episode still running
    loaded.load_replay_buffer(tmp_path / "buffer.pkl", truncate_last_traj=False)
    buffer, original = loaded.replay_buffer, model.replay_buffer
    assert isinstance(buffer, OffOnReplayBuffer)
    np.testing.assert_array_equal(buffer.mc_returns, original.mc_returns)
    np.testing.assert_array_equal(buffer.next_actions, original.next_actions)
    np.testing.assert_array_equal(buffer.episode_lengths, original.episode_lengths)
    assert buffer.truncation_value_fn is None  # mc_truncation="terminal"

    last_slot = original.pos - 1
    assert buffer.episode_lengths[0] > 0 and np.isnan(buffer.mc_returns[last_slot, 0]), "600 steps end mid-episode"
    loaded.learn(300, reset_num_timesteps=False)
    assert loaded.num_timesteps == 900
    # The env was reset by load: the episode open in the buffer was ended (cut), so its returns are known
    assert not np.isnan(buffer.mc_returns[last_slot, 0])


def test_loading_a_buffer_ends_its_running_episodes_unless_told_they_go_on(tmp_path):
    model = paper_offon_dqn("MlpPolicy", "CartPole-v1", seed=3, mc_truncation="terminal", **SMALL).learn(600)
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    length, last_slot = int(model.replay_buffer.episode_lengths[0]), model.replay_buffer.pos - 1
    episode = slice(last_slot - length + 1, last_slot + 1)
    assert length > 0 and np.isnan(model.replay_buffer.mc_returns[episode, 0]).all(), "600 steps end mid-episode"

    # A live model (its env mid-episode) loads another run's buffer: that run's episode must not chain into this one
    live = paper_offon_dqn("MlpPolicy", "CartPole-v1", seed=4, mc_truncation="terminal", **SMALL).learn(50)
    live.load_replay_buffer(tmp_path / "buffer.pkl")
    buffer = live.replay_buffer
    assert buffer.episode_lengths[0] == 0
    np.testing.assert_allclose(buffer.mc_returns[episode, 0], discounted_returns(buffer.rewards[episode, 0], 0.99), rtol=1e-5)

    live.load_replay_buffer(tmp_path / "buffer.pkl", truncate_last_traj=False)
    assert live.replay_buffer.episode_lengths[0] == length and np.isnan(live.replay_buffer.mc_returns[episode, 0]).all()


def test_loaded_buffer_gets_the_bootstrap_value_function_back(tmp_path):
    model = paper_offon_dqn("MlpPolicy", "CartPole-v1", **SMALL).learn(200)
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    with open(tmp_path / "buffer.pkl", "rb") as file:
        assert pickle.load(file).truncation_value_fn is None, "the pickled buffer holds no reference to the model"
    other = paper_offon_dqn("MlpPolicy", "CartPole-v1", **SMALL)
    other.load_replay_buffer(tmp_path / "buffer.pkl")
    assert other.replay_buffer.truncation_value_fn == other._target_state_values


def test_continued_learning_keeps_episodes_open():
    model = paper_offon_dqn(
        "MlpPolicy", "CartPole-v1", seed=0, **SMALL
    )  # seeded: where episodes end must not depend on test order
    buffer = model.replay_buffer
    linked = 0
    for _ in range(5):
        model.learn(8, reset_num_timesteps=False)
        last_slot = buffer.pos - 1
        was_running = buffer.episode_lengths[0] > 0
        model.learn(4, reset_num_timesteps=False)
        if was_running:
            # Same env, not reset: the running episode went on instead of being cut, so the action links up
            assert buffer.next_actions[last_slot, 0] == buffer.actions[last_slot + 1, 0, 0]
            linked += 1
    assert linked > 0, "some learn() call must have ended mid-episode"
    last_slot = buffer.pos - 1
    assert buffer.episode_lengths[0] > 0 and np.isnan(buffer.mc_returns[last_slot, 0]), "60 steps end mid-episode"
    model.learn(4)  # reset_num_timesteps=True resets the env: the running episode is cut and gets its returns
    assert not np.isnan(buffer.mc_returns[last_slot, 0])


# --- observation types, n-step, other buffers --------------------------------------------------------------------


def test_dict_observations():
    model = paper_offon_dqn(
        "MultiInputPolicy", SimpleMultiObsEnv(random_start=True), **{**SMALL, "learning_starts": 50, "batch_size": 8}
    )
    assert isinstance(model.replay_buffer, OffOnDictReplayBuffer)
    model.learn(200)
    assert not np.isnan(model.replay_buffer.mc_returns).all()


def test_image_observations():
    env = FakeImageEnv(screen_height=40, screen_width=40, n_channels=1, discrete=True)
    small_cnn = dict(**{**SMALL, "learning_starts": 50, "buffer_size": 300, "batch_size": 8, "policy_kwargs": None})
    model = paper_offon_dqn("CnnPolicy", env, **small_cnn).learn(120)
    assert not np.isnan(model.replay_buffer.mc_returns).all()
    assert model.replay_buffer.observations.dtype == np.uint8


def test_n_steps_uses_the_n_step_buffer_without_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = paper_offon_dqn("MlpPolicy", "CartPole-v1", n_steps=3, **SMALL)
        assert isinstance(model.replay_buffer, OffOnNStepReplayBuffer) and model.replay_buffer.n_steps == 3
        model.learn(300)
    assert model._n_updates > 0 and np.isfinite(model.replay_buffer.mc_returns).any()


def test_a_custom_n_step_buffer_gets_the_models_n_steps_and_gamma():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # n_steps is not ignored: SB3's warning must not fire
        model = paper_offon_dqn(
            "MlpPolicy", "CartPole-v1", n_steps=5, gamma=0.9, replay_buffer_class=OffOnNStepReplayBuffer, **SMALL
        )
    assert model.replay_buffer.n_steps == 5 and model.replay_buffer.gamma == 0.9
    # SB3's way for a custom buffer (the model's n_steps left at 1) still works
    kwargs = {"replay_buffer_class": OffOnNStepReplayBuffer, "replay_buffer_kwargs": {"n_steps": 4}}
    assert paper_offon_dqn("MlpPolicy", "CartPole-v1", **kwargs, **SMALL).replay_buffer.n_steps == 4


@pytest.mark.parametrize(
    "model_kwargs, buffer_kwargs",
    [
        ({"n_steps": 5, "replay_buffer_class": OffOnNStepReplayBuffer}, {"n_steps": 3}),
        ({"gamma": 0.9}, {"gamma": 0.99}),
        ({"n_steps": 3, "gamma": 0.9}, {"gamma": 0.95}),
    ],
)
def test_buffer_discounting_that_differs_from_the_models_names_it(model_kwargs, buffer_kwargs):
    key = next(iter(buffer_kwargs))
    with pytest.raises(ValueError, match=rf"replay_buffer_kwargs\['{key}'\].*model's `{key}`"):
        paper_offon_dqn("MlpPolicy", "CartPole-v1", replay_buffer_kwargs=buffer_kwargs, **model_kwargs, **SMALL)


def test_a_model_loaded_with_another_gamma_and_n_steps_builds_its_buffer_with_them(tmp_path):
    paper_offon_dqn("MlpPolicy", "CartPole-v1", n_steps=3, **SMALL).save(tmp_path / "model.zip")
    loaded = OffOnDQN.load(tmp_path / "model.zip", env=gym.make("CartPole-v1"), gamma=0.9, n_steps=5)
    assert loaded.replay_buffer.gamma == 0.9 and loaded.replay_buffer.n_steps == 5
    assert loaded.replay_buffer_kwargs == {}, "the model's own values are not saved as the caller's buffer arguments"


@pytest.mark.parametrize("saved_kwargs, key", [({"gamma": 0.9}, "gamma"), ({"n_steps": 3}, "n_steps")])
def test_load_replay_buffer_with_other_discounting_names_it_and_keeps_the_buffer(tmp_path, saved_kwargs, key):
    saved = paper_offon_dqn("MlpPolicy", "CartPole-v1", **saved_kwargs, **SMALL)
    saved.learn(20)
    saved.save_replay_buffer(tmp_path / "buffer.pkl")
    model = paper_offon_dqn("MlpPolicy", "CartPole-v1", **SMALL)
    own_buffer = model.replay_buffer
    with pytest.raises(ValueError, match=rf"replay buffer's `{key}`"):
        model.load_replay_buffer(tmp_path / "buffer.pkl")
    assert model.replay_buffer is own_buffer


def test_load_replay_buffer_with_the_same_discounting_loads_it(tmp_path):
    saved = paper_offon_dqn("MlpPolicy", "CartPole-v1", n_steps=3, gamma=0.9, **SMALL)
    saved.learn(20)
    saved.save_replay_buffer(tmp_path / "buffer.pkl")
    model = paper_offon_dqn("MlpPolicy", "CartPole-v1", n_steps=3, gamma=0.9, **SMALL)
    model.load_replay_buffer(tmp_path / "buffer.pkl")
    assert model.replay_buffer.pos == saved.replay_buffer.pos == 20
    # SB3's way to ask a custom buffer for n-step returns: the model's n_steps stays 1, the buffer's is the kwargs'
    kwargs = {"replay_buffer_class": OffOnNStepReplayBuffer, "replay_buffer_kwargs": {"n_steps": 4}}
    custom = paper_offon_dqn("MlpPolicy", "CartPole-v1", **kwargs, **SMALL)
    custom.learn(20)
    custom.save_replay_buffer(tmp_path / "custom.pkl")
    paper_offon_dqn("MlpPolicy", "CartPole-v1", **kwargs, **SMALL).load_replay_buffer(tmp_path / "custom.pkl")


@pytest.mark.parametrize("name, value", [("mc_mixing", "Max"), ("mc_initial_prob", 7.0)])
def test_load_checks_the_offon_arguments_it_is_given(tmp_path, name, value):
    paper_offon_dqn("MlpPolicy", "CartPole-v1", **SMALL).save(tmp_path / "model.zip")
    with pytest.raises(ValueError, match=name):
        OffOnDQN.load(tmp_path / "model.zip", custom_objects={name: value})
    with pytest.raises(ValueError, match=name):
        OffOnDQN.load(tmp_path / "model.zip", **{name: value})


def test_plain_buffer_warns_once_and_trains_with_qlearning():
    # With the default (Monte-Carlo and Sarsa) probabilities: a plain buffer has no returns or next actions, so every
    # target is Q-learning's and training is DQN's, bit for bit
    env_kwargs = dict(env_id="CartPole-v1", n_envs=2, seed=5)
    with pytest.warns(UserWarning, match="Q-learning targets only"):
        model = paper_offon_dqn("MlpPolicy", make_vec_env(**env_kwargs), replay_buffer_class=ReplayBuffer, seed=5, **SMALL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model.learn(600)
    dqn = DQN("MlpPolicy", make_vec_env(**env_kwargs), seed=5, **SMALL).learn(600)
    assert model._n_updates > 0
    assert_same_parameters(model, dqn)


# --- bad input ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, value",
    [
        ("mc_initial_prob", 1.5),
        ("mc_final_prob", -0.1),
        ("qlearning_initial_prob", 2.0),
        ("qlearning_final_prob", -1.0),
        ("mc_fraction", 0.0),
        ("qlearning_fraction", 1.2),
        ("mc_mixing", "average"),
        ("sarsa_target", "greedy"),
        ("mc_truncation", "ignore"),
        ("loss", "l1"),
    ],
)
def test_bad_input_names_the_parameter(name, value):
    with pytest.raises(ValueError, match=name):
        paper_offon_dqn("MlpPolicy", "CartPole-v1", **{name: value})


@pytest.mark.parametrize(
    "name",
    [
        "mc_initial_prob",
        "mc_final_prob",
        "mc_fraction",
        "qlearning_initial_prob",
        "qlearning_final_prob",
        "qlearning_fraction",
    ],
)
@pytest.mark.parametrize("value", ["0.5", None, float("nan"), True, np.bool_(False), [0.5]])
def test_bad_types_of_numbers_name_the_parameter(name, value):
    with pytest.raises(ValueError, match=f"`{name}` must be a real number"):
        paper_offon_dqn("MlpPolicy", "CartPole-v1", **{name: value})


@pytest.mark.parametrize("name", ["mc_mixing", "sarsa_target", "mc_truncation", "loss"])
@pytest.mark.parametrize("value", [None, 1, True, ["sample"], np.array(["huber", "mse"])])
def test_bad_types_of_options_name_the_parameter(name, value):
    with pytest.raises(ValueError, match=f"`{name}` must be one of"):
        paper_offon_dqn("MlpPolicy", "CartPole-v1", **{name: value})


def test_numpy_and_integer_probabilities_are_accepted():
    # What YAML files and NumPy code hand over: 1 (an int), np.float32 values
    model = paper_offon_dqn(
        "MlpPolicy", "CartPole-v1", mc_initial_prob=1, mc_final_prob=np.float32(0.25), qlearning_fraction=np.float64(0.5)
    )
    assert model.mc_schedule(1.0) == 1.0
    assert model.mc_schedule(0.0) == pytest.approx(0.25)


# --- logging -----------------------------------------------------------------------------------------------------


class RecordingWriter(KVWriter):
    def __init__(self):
        self.records = []

    def write(self, key_values, key_excluded, step=0):
        self.records.append(dict(key_values))


def test_training_statistics_are_logged(tmp_path):
    model = paper_offon_dqn(
        "MlpPolicy", "CartPole-v1", seed=0, tensorboard_log=str(tmp_path), **constant_probs(0.5, 0.5), **SMALL
    )
    writer = RecordingWriter()
    model.learn(1, tb_log_name="probe")  # sets up a logger; replaced below to capture what is written
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    model.learn(800, log_interval=1, reset_num_timesteps=False)
    train_records = [record for record in writer.records if "train/loss" in record]
    assert train_records
    record = train_records[-1]
    assert record["train/mc_prob"] == 0.5 and record["train/qlearning_prob"] == 0.5
    # Each record covers one training call (32 samples here): average over the calls. MC: delta1 times the share of
    # sampled transitions whose return is known; Sarsa: half of the rest, where the next action is known
    mc_share = np.mean([record["train/mc_target_fraction"] for record in train_records])
    sarsa_share = np.mean([record["train/sarsa_target_fraction"] for record in train_records])
    assert 0.2 < mc_share <= 0.5
    assert 0.1 < sarsa_share < 0.4
    assert np.isfinite(record["train/q_mc_gap"])
    assert (tmp_path / "probe_1").is_dir(), "tensorboard logs are written"


def test_target_statistics_by_hand():
    model = paper_offon_dqn("MlpPolicy", "CartPole-v1", **SMALL)
    writer = RecordingWriter()
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    # Two gradient steps of two samples; G is known for one sample of each
    q_taken = th.tensor([[1.0], [2.0], [4.0], [0.5]])
    returns = th.tensor([[0.0], [float("nan")], [float("nan")], [1.0]])
    losses = th.tensor([1.0, 3.0])
    model._record_target_statistics(losses, q_taken, returns, n_mc_targets=1, n_sarsa_targets=2)
    model.logger.dump()
    assert "train/mc_bound_active_fraction" not in writer.records[-1], "only logged for mc_mixing='max'"
    model.mc_mixing = "max"
    bound_active = [th.tensor([[True], [False]]), th.tensor([[False], [False]])]
    model._record_target_statistics(losses, q_taken, returns, 1, 2, bound_active=bound_active)
    model.logger.dump()
    assert writer.records[-1]["train/mc_bound_active_fraction"] == pytest.approx(0.25)
    model.mc_mixing = "sample"
    record = writer.records[-1]
    assert record["train/loss"] == pytest.approx(2.0)
    assert record["train/mc_target_fraction"] == pytest.approx(0.25)
    assert record["train/sarsa_target_fraction"] == pytest.approx(0.5)
    assert record["train/q_mc_gap"] == pytest.approx(((1.0 - 0.0) + (0.5 - 1.0)) / 2)
    # No known return: no gap to report
    model._record_target_statistics(losses[:1], q_taken[:2], th.full((2, 1), float("nan")), 0, 0)
    model.logger.dump()
    assert "train/q_mc_gap" not in writer.records[-1]


def test_tensorboard_default_run_name(tmp_path):
    paper_offon_dqn("MlpPolicy", "CartPole-v1", tensorboard_log=str(tmp_path), **SMALL).learn(200)
    assert (tmp_path / "OffOnDQN_1").is_dir()


def test_discrete_observations_with_truncated_episodes():
    # IdentityEnv ends every episode by truncation: the bootstrap sees Discrete observations in the buffer's layout
    model = paper_offon_dqn("MlpPolicy", IdentityEnv(5, ep_length=20), gamma=0.9, **{**SMALL, "learning_starts": 30})
    model.learn(110)
    buffer, n = model.replay_buffer, model.replay_buffer.pos
    open_episode = slice(n - n % 20, n)
    assert n % 20 != 0 and np.isnan(buffer.mc_returns[open_episode, 0]).all(), "learn() stopped mid-episode"
    assert np.isfinite(buffer.mc_returns[: open_episode.start, 0]).all(), "the finished (truncated) episodes have returns"
    # A second learn() resets the env: the open episode ends as truncated at its last stored next observation, with
    # the target network as it is now (no gradient step comes between the two)
    tail = max_target_q(model, buffer.next_observations[n - 1, 0])
    expected_open = discounted_returns(buffer.rewards[open_episode, 0], 0.9, tail)
    model.learn(8)
    np.testing.assert_allclose(buffer.mc_returns[open_episode, 0], expected_open, rtol=1e-5)
    assert buffer.next_actions[n - 1, 0] == -1, "the cut episode does not chain into the next"
