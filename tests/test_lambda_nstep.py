"""mc_mixing="lambda" with n_steps > 1: the lambda-return over n-step windows, by hand, against a literal transcription
of the formula, and at lambda = 0 against the n-step target of SB3's own NStepReplayBuffer."""

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.buffers import NStepReplayBuffer
from stable_baselines3.common.env_util import make_vec_env
from test_lambda_returns import (
    GAMMA,
    N_ACTIONS,
    OBS_SPACE,
    SMALL,
    cache_of,
    fake_target,
    model_target,
    random_episodes,
    returns_by_slot,
    step,
)
from test_lambda_returns import assert_matches_reference as assert_matches

from sb3_offon import OffOnDQN, OffOnNStepReplayBuffer
from sb3_offon.common.lambda_layout import choose_blocks
from sb3_offon.common.lambda_returns import backward_recurrence

LAMBDA = dict(mc_mixing="lambda", mc_initial_prob=0.9, mc_final_prob=0.9, qlearning_initial_prob=0.0, qlearning_final_prob=0.0)


def make_buffer(n_steps, buffer_size=16, n_envs=1):
    return OffOnNStepReplayBuffer(
        buffer_size * n_envs, OBS_SPACE, spaces.Discrete(N_ACTIONS), "cpu", n_envs=n_envs, n_steps=n_steps, gamma=GAMMA
    )


def reference_nstep_lambda_returns(buffer, target, lam, qlearning_prob, cut_is_terminal=False, same_block=None, gamma=GAMMA):
    """
    The formula of lambda_returns' docstring for n-step windows, transcribed step by step with Python loops.

    :param same_block: (chronological index, env, its successor's index) -> whether both are in one block (default: yes)
    :param gamma: the discount factor
    :return: {(slot, env): G}
    """
    n, size = buffer.n_steps, buffer.buffer_size
    oldest, n_stored, first = buffer.chronology()
    newest_slot = (buffer.pos - 1) % size
    returns = {}
    for env in range(buffer.n_envs):
        by_index = {}
        for index in reversed(range(first, n_stored)):
            slot = (oldest + index) % size
            # The window: step on while the episode went on, up to n steps
            k, total = 0, 0.0
            while True:
                total += gamma**k * float(buffer.rewards[(slot + k) % size, env])
                k += 1
                if k == n or buffer.next_actions[(slot + k - 1) % size, env] < 0:
                    break
            end = (slot + k - 1) % size
            value, greedy = (float(x[0]) for x in target(buffer.next_observations[end, env][None]))
            next_action = int(buffer.next_actions[end, env])
            terminated = buffer.dones[end, env] and not buffer.timeouts[end, env]
            running_newest = end == newest_slot and buffer.episode_starts[env] < buffer._n_adds
            successor = index + n
            linked = next_action >= 0 and successor < n_stored and (same_block is None or same_block(index, env, successor))
            if terminated:
                g = total
            elif not linked:
                cut_without_value = cut_is_terminal and next_action < 0 and not running_newest
                g = total + gamma**k * (0.0 if cut_without_value else value)
            else:
                c = 1.0 if next_action == greedy else 1.0 - qlearning_prob
                g = total + gamma**k * ((1 - lam * c) * value + lam * c * by_index[successor])
            by_index[index] = g
            returns[(slot, env)] = g
    return returns


def five_steps(buffer, actions=(0, 1, 2, 3, 4), dones=None, truncated=None):
    """Rewards 1..5 at next states 11..15 (V = the id, greedy action = id % 5: actions 0..4 are greedy)."""
    for t in range(5):
        last = t == 4
        step(buffer, [t + 1.0], [actions[t]], [11 + t], dones=dones if last else None, truncated=truncated if last else None)


# --- the recursion with a stride ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("stride", [1, 2, 3, 5])
def test_strided_backward_recurrence_matches_a_loop(stride):
    rng = np.random.default_rng(stride)
    for length in (0, 1, 2, 3, 4, 7, 10, 64):
        inputs = rng.normal(size=(3, length))
        coefficients = rng.uniform(0, 1, size=(3, length)) * (rng.uniform(size=(3, length)) > 0.1)
        expected = np.zeros_like(inputs)
        for t in reversed(range(length)):
            expected[:, t] = inputs[:, t] + coefficients[:, t] * (expected[:, t + stride] if t + stride < length else 0.0)
        np.testing.assert_allclose(backward_recurrence(inputs, coefficients, stride=stride), expected, rtol=1e-12, atol=1e-12)


# --- by hand (gamma = lambda = 0.5, n = 2) ---------------------------------------------------------------------------------


def test_terminated_episode_by_hand():
    buffer = make_buffer(n_steps=2)
    five_steps(buffer, dones=[True])
    # Windows: [0,1] [1,2] [2,3] [3,4] [4]; G_4 = 5; G_3 = 4 + 0.5 * 5 = 6.5 (its window ends the episode);
    # G_2 = (3 + 0.5 * 4) + 0.25 * (0.5 * V(s_4) + 0.5 * G_4) = 5 + 0.25 * (7 + 2.5) = 7.375;
    # G_1 = 3.5 + 0.25 * (0.5 * 13 + 0.5 * 6.5) = 5.9375; G_0 = 2 + 0.25 * (0.5 * 12 + 0.5 * 7.375) = 4.421875
    np.testing.assert_allclose(returns_by_slot(cache_of(buffer)), [4.421875, 5.9375, 7.375, 6.5, 5.0])


@pytest.mark.parametrize("cut_is_terminal", [False, True])
def test_truncated_episode_by_hand(cut_is_terminal):
    buffer = make_buffer(n_steps=2)
    for t in range(3):  # rewards 1, 2, 3 at next states 11, 12, 13, cut by a time limit after the third
        step(buffer, [t + 1.0], [t], [11 + t], dones=[t == 2], truncated=[t == 2])
    returns = returns_by_slot(cache_of(buffer, cut_is_terminal=cut_is_terminal))
    if cut_is_terminal:
        # G_2 = 3; G_1 = 2 + 0.5 * 3 = 3.5; G_0 = 2 + 0.25 * (0.5 * 12 + 0.5 * 3) = 3.875
        np.testing.assert_allclose(returns, [3.875, 3.5, 3.0])
    else:
        # G_2 = 3 + 0.5 * 13 = 9.5; G_1 = 3.5 + 0.25 * 13 = 6.75; G_0 = 2 + 0.25 * (0.5 * 12 + 0.5 * 9.5) = 4.6875
        np.testing.assert_allclose(returns, [4.6875, 6.75, 9.5])


def test_running_episode_windows_stop_at_the_newest_transition():
    buffer = make_buffer(n_steps=3)
    for t in range(3):
        step(buffer, [t + 1.0], [t], [11 + t])
    # G_2 = 3 + 0.5 * 13 = 9.5; G_1 = (2 + 0.5 * 3) + 0.25 * 13 = 6.75; G_0 = (1 + 1 + 0.75) + 0.125 * 13 = 4.375
    np.testing.assert_allclose(returns_by_slot(cache_of(buffer, lam=0.9)), [4.375, 6.75, 9.5])


@pytest.mark.parametrize("qlearning_prob, expected_g1", [(1.0, 3.5 + 0.25 * 13), (0.0, 5.9375)])
def test_trace_cut_at_the_action_after_the_window(qlearning_prob, expected_g1):
    buffer = make_buffer(n_steps=2)
    five_steps(buffer, actions=(0, 1, 2, 0, 4), dones=[True])  # a_3 = 0 is not greedy at s_3 (13: greedy 3)
    cache = cache_of(buffer, qlearning_prob=qlearning_prob)
    # Only G_1 goes on through a_3; a_1 .. a_2 inside windows are not checked (G_0's trace goes on through a_2)
    np.testing.assert_allclose(returns_by_slot(cache), [4.421875, expected_g1, 7.375, 6.5, 5.0])
    assert cache.trace_cut_fraction == (0.0 if qlearning_prob == 0.0 else pytest.approx(1 / 3))  # of G_0, G_1, G_2


# --- several envs, a ring that wraps, blocks ------------------------------------------------------------------------------


@pytest.mark.parametrize("n_steps", [2, 3])
@pytest.mark.parametrize("n_adds", [9, 40], ids=["partly-filled", "wrapped"])
@pytest.mark.parametrize("qlearning_prob, cut_is_terminal", [(1.0, False), (0.0, True), (0.3, False)])
def test_several_envs_and_a_wrapping_ring_match_the_formula(n_steps, n_adds, qlearning_prob, cut_is_terminal):
    buffer = make_buffer(n_steps, buffer_size=16, n_envs=3)
    random_episodes(buffer, n_adds)
    cache = cache_of(buffer, lam=0.8, qlearning_prob=qlearning_prob, cut_is_terminal=cut_is_terminal)
    assert_matches(cache, reference_nstep_lambda_returns(buffer, fake_target, 0.8, qlearning_prob, cut_is_terminal))


@pytest.mark.parametrize("n_steps", [1, 2, 4])
def test_lambda_0_is_the_n_step_target_of_sb3s_buffer(n_steps):
    """At lambda = 0 every return is n-step DQN's target, r^(k) + gamma^k * (1 - terminated) * V, as SB3 samples it."""
    buffer = make_buffer(max(n_steps, 2), buffer_size=16, n_envs=3)
    buffer.n_steps = n_steps  # an n-step buffer with n = 1 is a one-step buffer
    random_episodes(buffer, 40, seed=4)
    cache = cache_of(buffer, lam=0.0)
    # SB3's sampling draws the env of each slot: draw those envs, then let SB3 sample with the same seed
    np.random.seed(0)
    sampled_envs = np.random.randint(0, buffer.n_envs, size=len(cache))
    by_slot_env = {(int(s), int(e)): g for s, e, g in zip(cache.slots, cache.envs, cache.returns, strict=True)}
    np.random.seed(0)
    samples = NStepReplayBuffer._get_samples(buffer, cache.slots)
    values, _ = fake_target(samples.next_observations.numpy())
    sb3_targets = (
        samples.rewards.numpy().reshape(-1)
        + samples.discounts.numpy().reshape(-1) * (1 - samples.dones.numpy().reshape(-1)) * values
    )
    ours = np.array([by_slot_env[(int(s), int(e))] for s, e in zip(cache.slots, sampled_envs, strict=True)])
    np.testing.assert_allclose(ours, sb3_targets, rtol=1e-5, atol=1e-5)


def test_blocks_cut_the_trace_where_the_successor_is_past_the_block():
    buffer = make_buffer(n_steps=3, buffer_size=64, n_envs=2)
    random_episodes(buffer, 100, seed=1)
    _, n_stored, first = buffer.chronology()
    np.random.seed(3)
    block_envs, block_starts, block_lengths = choose_blocks(buffer.n_envs, first, n_stored, 8, 40)
    np.random.seed(3)
    cache = cache_of(buffer, lam=0.8, n_wanted=40, block_size=8)
    block_of = {}
    for number, (env, start, length) in enumerate(zip(block_envs, block_starts, block_lengths, strict=True)):
        for index in range(start, start + length):
            block_of[(int(index), int(env))] = number

    def same_block(index, env, successor):
        block = block_of.get((index, env))  # the reference also runs over transitions outside the cache
        return block is not None and block_of.get((successor, env)) == block

    reference = reference_nstep_lambda_returns(buffer, fake_target, 0.8, 1.0, same_block=same_block)
    assert len(cache) == len(block_of)
    for slot, env, value in zip(cache.slots, cache.envs, cache.returns, strict=True):
        assert value == pytest.approx(reference[(int(slot), int(env))], rel=1e-6, abs=1e-6)


# --- the model ------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n_envs", [1, 2])
def test_model_with_n_steps_matches_the_formula_with_its_target_network(n_envs, tmp_path):
    env = make_vec_env("CartPole-v1", n_envs=n_envs, seed=0)
    model = OffOnDQN("MlpPolicy", env, seed=0, buffer_size=300, gamma=0.9, n_steps=3, **SMALL, **LAMBDA)
    assert isinstance(model.replay_buffer, OffOnNStepReplayBuffer) and model.replay_buffer.n_steps == 3
    model.learn(400)  # the ring wraps; episodes of different lengths per env
    model._lambda_cache = None
    cache = model._refreshed_lambda_cache(10**6)  # the whole buffer, one block per env
    reference = reference_nstep_lambda_returns(model.replay_buffer, model_target(model), model.mc_prob, 0.0, gamma=0.9)
    assert_matches(cache, reference)
    model.save(tmp_path / "model")
    loaded = OffOnDQN.load(tmp_path / "model", env=env)
    assert (loaded.n_steps, loaded.mc_mixing) == (3, "lambda")
    loaded.learn(100, reset_num_timesteps=False)
    assert loaded._lambda_cache is not None
