"""Prioritised replay on the Off-On buffers: sampling, importance weights and priorities against hand-computed values,
in OffOnDQN's every target mode and OffOnQRDQN's lambda cache."""

import pickle

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import NStepReplayBuffer, ReplayBuffer
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.envs import SimpleMultiObsEnv
from test_train_loop import count_read_backs  # noqa: F401  (a fixture)

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.common.prioritized_buffers import (
    PrioritizedOffOnDictReplayBuffer,
    PrioritizedOffOnNStepReplayBuffer,
    PrioritizedOffOnReplayBuffer,
)

OBS_SPACE = spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float32)
ACTIONS = spaces.Discrete(3)
SMALL = dict(learning_starts=50, batch_size=16, train_freq=4, target_update_interval=40, buffer_size=500)


def make_buffer(buffer_size=8, n_envs=1, alpha=0.5, beta=0.4, **kwargs):
    return PrioritizedOffOnReplayBuffer(
        buffer_size * n_envs, OBS_SPACE, ACTIONS, device="cpu", n_envs=n_envs, gamma=0.5, alpha=alpha, beta=beta, **kwargs
    )


def fill(buffer, n_steps, episode_length=4):
    for t in range(n_steps):
        n_envs = buffer.n_envs
        obs = np.full((n_envs, 1), t, dtype=np.float32)
        dones = np.full(n_envs, t % episode_length == episode_length - 1)
        buffer.add(
            obs, obs + 1, np.zeros((n_envs, 1), dtype=np.int64), np.full(n_envs, float(t), np.float32), dones, [{}] * n_envs
        )


# --- the buffer -----------------------------------------------------------------------------------------------------


def test_new_transitions_enter_at_the_highest_priority_so_far():
    buffer = make_buffer()
    fill(buffer, 3)
    np.testing.assert_allclose(buffer.tree.values(np.arange(3)), 1.0)  # 1 before any update (1^alpha)
    buffer.update_priorities(np.array([0, 1]), np.array([0, 0]), np.array([3.0, -0.5]))
    np.testing.assert_allclose(buffer.tree.values(np.arange(2)), np.sqrt([3.0 + 1e-6, 0.5 + 1e-6]))
    assert buffer.max_priority == pytest.approx(3.0 + 1e-6)
    fill(buffer, 1)
    assert buffer.tree.values(np.array([3]))[0] == pytest.approx(np.sqrt(3.0 + 1e-6))


def test_sampling_frequencies_follow_p_to_the_alpha():
    buffer = make_buffer(buffer_size=6, alpha=0.7)
    fill(buffer, 6)
    errors = np.array([0.1, 1.0, 2.0, 4.0, 0.5, 3.0])
    buffer.update_priorities(np.arange(6), np.zeros(6, dtype=int), errors)
    expected = (errors + 1e-6) ** 0.7
    expected /= expected.sum()
    buffer.rng = np.random.default_rng(0)  # a fixed seed for the draws
    n_draws = 100_000
    slots, envs, _ = buffer.draw(n_draws)
    assert np.all(envs == 0)
    frequencies = np.bincount(slots, minlength=6) / n_draws
    # stratified draws vary less than independent ones: 5 binomial standard errors bound them
    assert np.all(np.abs(frequencies - expected) <= 5 * np.sqrt(expected * (1 - expected) / n_draws)), frequencies


def test_importance_weights_are_hand_computed():
    buffer = make_buffer(buffer_size=4, alpha=1.0, beta=0.5)
    fill(buffer, 4)
    buffer.update_priorities(np.arange(4), np.zeros(4, dtype=int), np.array([1.0, 2.0, 4.0, 1.0]) - 1e-6)
    probabilities = np.array([1.0, 2.0, 4.0, 1.0]) / 8.0
    # (N P(i))^-beta / max_k (N P(k))^-beta, the maximum at the smallest priority (1/8)
    expected = (4 * probabilities) ** -0.5 / (4 * 1 / 8) ** -0.5
    np.testing.assert_allclose(buffer.weights(probabilities), expected, rtol=1e-6)
    np.testing.assert_allclose(expected, [1.0, 1 / np.sqrt(2), 0.5, 1.0])
    buffer.rng = np.random.default_rng(1)  # a fixed seed for the draws
    slots, _, weights = buffer.draw(64)
    np.testing.assert_allclose(weights, expected[slots], rtol=1e-6)  # each draw's weight is its probability's


def test_beta_anneals_to_its_final_value():
    buffer = make_buffer(beta=0.4, final_beta=1.0)
    buffer.anneal_beta(1.0)
    assert buffer.beta == pytest.approx(0.4)
    buffer.anneal_beta(0.5)
    assert buffer.beta == pytest.approx(0.7)
    buffer.anneal_beta(0.0)
    assert buffer.beta == pytest.approx(1.0)


def test_a_wrapped_ring_and_several_envs():
    buffer = make_buffer(buffer_size=4, n_envs=2)
    fill(buffer, 4)
    buffer.update_priorities(np.array([0, 0, 1]), np.array([0, 1, 1]), np.array([5.0, 0.0, 2.0]))
    assert buffer.tree.values(buffer.leaves(np.array([0]), np.array([1])))[0] == pytest.approx(np.sqrt(1e-6))
    fill(buffer, 1)  # overwrites slot 0 in both env columns: the new transitions at the highest priority (5)
    np.testing.assert_allclose(buffer.tree.values(buffer.leaves(np.array([0, 0]), np.array([0, 1]))), np.sqrt(5.0 + 1e-6))
    assert buffer.n_transitions() == 8
    buffer.rng = np.random.default_rng(2)  # a fixed seed for the draws
    slots, envs, _ = buffer.draw(2000)
    assert set(envs.tolist()) == {0, 1} and slots.max() < 4


def test_alpha_zero_is_uniform_with_unit_weights_and_sb3s_samples():
    buffer = make_buffer(buffer_size=16, alpha=0.0)
    fill(buffer, 10)
    buffer.update_priorities(np.arange(10), np.zeros(10, dtype=int), np.linspace(0, 9, 10))
    buffer.rng = np.random.default_rng(3)  # a fixed seed for the draws
    batches, slots, _, weights = buffer.sample_prioritized(50, 32)
    np.testing.assert_array_equal(weights, 1.0)
    frequencies = np.bincount(slots, minlength=10) / len(slots)
    assert np.all(np.abs(frequencies - 0.1) <= 5 * np.sqrt(0.09 / len(slots))), frequencies
    # The same targets' inputs as SB3's samples of those transitions
    theirs = ReplayBuffer._get_samples(buffer, slots)
    ours = batches.samples
    for name in ("observations", "actions", "next_observations", "dones", "rewards"):
        np.testing.assert_array_equal(getattr(ours, name).numpy(), getattr(theirs, name).numpy(), err_msg=name)
    assert ours.discounts is None and theirs.discounts is None


def test_n_step_samples_are_sb3s_n_step_samples():
    buffer = PrioritizedOffOnNStepReplayBuffer(16, OBS_SPACE, ACTIONS, device="cpu", n_steps=3, gamma=0.5)
    fill(buffer, 11, episode_length=5)
    buffer.rng = np.random.default_rng(4)  # a fixed seed for the draws
    batches, slots, _, _ = buffer.sample_prioritized(4, 16)
    theirs = NStepReplayBuffer._get_samples(buffer, slots)
    for name in ("observations", "next_observations", "dones", "rewards", "discounts"):
        np.testing.assert_allclose(getattr(batches.samples, name).numpy(), getattr(theirs, name).numpy(), err_msg=name)


def test_the_tree_survives_pickling():
    buffer = make_buffer()
    fill(buffer, 6)
    buffer.update_priorities(np.arange(6), np.zeros(6, dtype=int), np.arange(6.0))
    loaded = pickle.loads(pickle.dumps(buffer))
    np.testing.assert_array_equal(loaded.tree.values(np.arange(8)), buffer.tree.values(np.arange(8)))
    assert loaded.max_priority == buffer.max_priority
    first = buffer.draw(10)  # the generator's state was saved with the rest
    second = loaded.draw(10)
    for ours, theirs in zip(first, second, strict=True):
        np.testing.assert_array_equal(ours, theirs)


@pytest.mark.parametrize(
    "name, value", [("alpha", -0.1), ("beta", 1.5), ("final_beta", -1), ("epsilon", 0.0), ("alpha", "0.5")]
)
def test_bad_arguments_name_the_parameter(name, value):
    with pytest.raises(ValueError, match=name):
        make_buffer(**{"alpha": 0.5, "beta": 0.4, name: value})


def test_optimize_memory_usage_is_refused():
    with pytest.raises(ValueError, match="optimize_memory_usage"):
        PrioritizedOffOnReplayBuffer(
            16, OBS_SPACE, ACTIONS, device="cpu", optimize_memory_usage=True, handle_timeout_termination=False
        )


# --- the algorithms -------------------------------------------------------------------------------------------------

MODES = {
    "lambda": {},
    "sample": dict(mc_mixing="sample", mc_initial_prob=0.5, mc_final_prob=0.5, qlearning_initial_prob=0.5),
    "convex": dict(mc_mixing="convex", mc_initial_prob=0.5, mc_final_prob=0.5),
    "max": dict(mc_mixing="max"),
}


@pytest.mark.parametrize("mode", sorted(MODES))
@pytest.mark.parametrize("n_steps", [1, 3])
def test_offon_dqn_trains_and_updates_priorities(mode, n_steps):
    buffer_class = PrioritizedOffOnNStepReplayBuffer if n_steps > 1 else PrioritizedOffOnReplayBuffer
    env = make_vec_env("CartPole-v1", n_envs=2, seed=0)
    model = OffOnDQN("MlpPolicy", env, seed=0, n_steps=n_steps, replay_buffer_class=buffer_class, **SMALL, **MODES[mode])
    model.learn(400)
    tree = model.replay_buffer.tree
    values = tree.values(np.arange(model.replay_buffer.n_transitions()))
    assert np.all(values > 0) and len(np.unique(values)) > 10  # trained transitions got their own priorities
    assert model.replay_buffer.beta > model.replay_buffer.initial_beta  # annealed with progress


def test_dict_observations():
    model = OffOnDQN(
        "MultiInputPolicy",
        SimpleMultiObsEnv(random_start=True),
        seed=0,
        replay_buffer_class=PrioritizedOffOnDictReplayBuffer,
        **SMALL,
    )
    model.learn(200)
    assert len(np.unique(model.replay_buffer.tree.values(np.arange(200)))) > 10


def test_the_lambda_cache_samples_by_priority_and_weights_match():
    model = OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, replay_buffer_class=PrioritizedOffOnReplayBuffer, **SMALL)
    model.learn(300)
    buffer = model.replay_buffer
    buffer.rng = np.random.default_rng(6)
    cache, entries, weights = model._draw_prioritized_lambda_entries(4000)
    priorities = buffer.tree.values(buffer.leaves(cache.slots, cache.envs))
    live = buffer.holds_transition(cache.added_at)
    probabilities = np.where(live, priorities, 0.0) / np.where(live, priorities, 0.0).sum()
    smallest = probabilities[probabilities > 0].min()
    np.testing.assert_allclose(weights, (probabilities[entries] / smallest) ** -buffer.beta, rtol=1e-5)
    frequencies = np.bincount(entries, minlength=len(cache)) / len(entries)
    top = np.argsort(probabilities)[-5:]
    assert np.all(np.abs(frequencies[top] - probabilities[top]) <= 5 * np.sqrt(probabilities[top] / len(entries)))


def test_the_lambda_cache_priorities_follow_the_errors():
    model = OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, replay_buffer_class=PrioritizedOffOnReplayBuffer, **SMALL)
    model.learn(300)
    cache = model._lambda_cache
    buffer = model.replay_buffer
    entries = np.array([0, 1, 2])
    model._update_lambda_priorities(cache, entries, np.array([2.0, -3.0, 0.0]))
    expected = np.power(np.array([2.0, 3.0, 0.0]) + buffer.epsilon, buffer.alpha)
    np.testing.assert_allclose(cache.tree.values(entries), expected)
    np.testing.assert_allclose(buffer.tree.values(buffer.leaves(cache.slots[entries], cache.envs[entries])), expected)
    # The errors of a training call are float32 (read back from the loss): both trees hold the same p^alpha, bit for bit
    entries = np.array([3, 4, 5, 3])  # drawn with replacement: an entry trained twice keeps its last error, in both trees
    model._update_lambda_priorities(cache, entries, np.array([0.1, -1.7, 2.3, 0.3], dtype=np.float32))
    np.testing.assert_array_equal(
        cache.tree.values(entries), buffer.tree.values(buffer.leaves(cache.slots[entries], cache.envs[entries]))
    )
    np.testing.assert_array_equal(cache.tree.values([3]), np.power(np.float64(np.float32(0.3)) + buffer.epsilon, buffer.alpha))


def test_offon_qrdqn_with_prioritised_replay(tmp_path):
    model = OffOnQRDQN(
        "MlpPolicy",
        "CartPole-v1",
        seed=0,
        replay_buffer_class=PrioritizedOffOnReplayBuffer,
        policy_kwargs=dict(n_quantiles=7, net_arch=[16]),
        **SMALL,
    )
    model.learn(300)
    assert len(np.unique(model.replay_buffer.tree.values(np.arange(300)))) > 10
    model.save_replay_buffer(tmp_path / "buffer")
    before = model.replay_buffer.tree.values(np.arange(300))
    model.load_replay_buffer(tmp_path / "buffer")
    np.testing.assert_array_equal(model.replay_buffer.tree.values(np.arange(300)), before)


@pytest.mark.parametrize(
    "algo, options",
    [(OffOnDQN, {}), (OffOnDQN, MODES["sample"]), (OffOnQRDQN, {"policy_kwargs": dict(n_quantiles=5)})],
    ids=["lambda", "sample", "qrdqn"],
)
def test_read_backs_do_not_grow_with_gradient_steps(count_read_backs, algo, options):  # noqa: F811
    def read_backs(gradient_steps):
        model = algo(
            "MlpPolicy",
            "CartPole-v1",
            seed=0,
            gradient_steps=gradient_steps,
            replay_buffer_class=PrioritizedOffOnReplayBuffer,
            **{**SMALL, **options},
        )
        model.learn(200)
        model._lambda_cache = None
        before = count_read_backs["n"]
        model.train(gradient_steps, batch_size=16)
        return count_read_backs["n"] - before

    assert read_backs(4) == read_backs(32)


def test_weighted_quantile_loss_with_unit_weights_is_the_loss():
    from sb3_offon.common.quantile_loss import WeightedQuantileHuberLoss, per_sample_quantile_huber_loss, quantile_huber_loss

    th.manual_seed(0)
    current = th.randn(8, 5, requires_grad=True)
    targets = th.randn(8, 5) * 2
    plain = quantile_huber_loss(current, targets)
    (plain_gradient,) = th.autograd.grad(plain, current)
    weighted, errors = WeightedQuantileHuberLoss.apply(current, targets, th.ones(8))
    (weighted_gradient,) = th.autograd.grad(weighted, current)
    th.testing.assert_close(weighted, plain)
    th.testing.assert_close(weighted_gradient, plain_gradient)
    weights = th.rand(8)
    per_sample = per_sample_quantile_huber_loss(current, targets)
    th.testing.assert_close(WeightedQuantileHuberLoss.apply(current, targets, weights)[0], (weights * per_sample).mean())
    assert th.equal(errors, per_sample) and not errors.requires_grad
    th.testing.assert_close(per_sample.mean(), plain.detach())
