"""Bookkeeping of the Off-On replay buffers, checked against returns and next actions computed by hand."""

import pickle

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_offon import OffOnDictReplayBuffer, OffOnNStepReplayBuffer, OffOnReplayBuffer
from sb3_offon.common.buffers import discounted_returns

OBS_SPACE = spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float32)
ACTION_SPACE = spaces.Discrete(5)
GAMMA = 0.5


def make_buffer(buffer_size=16, n_envs=1, buffer_class=OffOnReplayBuffer, **kwargs):
    return buffer_class(buffer_size * n_envs, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=n_envs, gamma=GAMMA, **kwargs)


def step(buffer, rewards, actions, dones=None, truncated=None, obs_ids=None, next_obs_ids=None):
    """Add one transition per env. Observations carry an id so that tests can tell which state a value came from."""
    n_envs = buffer.n_envs
    dones = np.zeros(n_envs, dtype=bool) if dones is None else np.asarray(dones, dtype=bool)
    truncated = np.zeros(n_envs, dtype=bool) if truncated is None else np.asarray(truncated, dtype=bool)
    obs = np.zeros((n_envs, 1), np.float32) if obs_ids is None else np.asarray(obs_ids, np.float32).reshape(n_envs, 1)
    next_obs = obs + 1000 if next_obs_ids is None else np.asarray(next_obs_ids, np.float32).reshape(n_envs, 1)
    infos = [{"TimeLimit.truncated": bool(truncated[i])} if dones[i] else {} for i in range(n_envs)]
    buffer.add(obs, next_obs, np.asarray(actions).reshape(n_envs, 1), np.asarray(rewards, np.float32), dones, infos)


def test_discounted_returns_by_hand():
    np.testing.assert_allclose(discounted_returns(np.array([1.0, 2.0, 3.0]), 0.5), [2.75, 3.5, 3.0])
    # With a tail value V after the last step: G_2 = 3 + 0.5 * 10
    np.testing.assert_allclose(discounted_returns(np.array([1.0, 2.0, 3.0]), 0.5, tail_value=10.0), [4.0, 6.0, 8.0])
    # Long episodes stay exact (no gamma^-t blow-up): 1 + gamma + gamma^2 + ... -> 1 / (1 - gamma)
    long_returns = discounted_returns(np.ones(20_000), 0.99)
    assert np.isfinite(long_returns).all()
    assert long_returns[0] == pytest.approx(100.0, rel=1e-6)
    assert long_returns[-1] == 1.0


def test_terminated_episode_returns_appear_when_it_ends():
    buffer = make_buffer()
    step(buffer, [1.0], [0])
    step(buffer, [2.0], [1])
    assert np.isnan(buffer.mc_returns[:2, 0]).all(), "returns are unknown while the episode runs"
    step(buffer, [3.0], [2], dones=[True])
    np.testing.assert_allclose(buffer.mc_returns[:3, 0], [2.75, 3.5, 3.0])
    assert np.isnan(buffer.mc_returns[3:, 0]).all()
    assert buffer.episode_lengths[0] == 0, "Omega is cleared when the episode ends"


@pytest.mark.parametrize("bootstrap", [True, False])
def test_truncated_episode_bootstrap_or_terminal(bootstrap):
    buffer = make_buffer()
    seen = []

    def state_values(final_observations):
        seen.append(np.array(final_observations))
        return np.full(len(final_observations), 10.0)

    buffer.truncation_value_fn = state_values if bootstrap else None
    step(buffer, [1.0], [0])
    step(buffer, [2.0], [1])
    step(buffer, [3.0], [2], dones=[True], truncated=[True], next_obs_ids=[77])
    if bootstrap:
        # G_2 = 3 + 0.5 * 10 = 8, G_1 = 2 + 0.5 * 8 = 6, G_0 = 1 + 0.5 * 6 = 4
        np.testing.assert_allclose(buffer.mc_returns[:3, 0], [4.0, 6.0, 8.0])
        assert len(seen) == 1 and seen[0].reshape(-1).tolist() == [77.0], "bootstrapped from the final observation"
    else:
        np.testing.assert_allclose(buffer.mc_returns[:3, 0], [2.75, 3.5, 3.0])


def test_dropped_truncation_leaves_returns_unknown_and_keeps_terminated_ones():
    buffer = make_buffer(n_envs=2)
    buffer.drop_truncated_returns = True
    buffer.truncation_value_fn = lambda obs: pytest.fail("a dropped truncation must not be bootstrapped")
    # env 0: episode A = [1, 1] truncated at step 1, then episode B = [2, 2] terminated at step 3
    # env 1: one episode [10, 0, 0, 8] terminated at step 3
    step(buffer, [1, 10], [0, 0])
    step(buffer, [1, 0], [1, 1], dones=[True, False], truncated=[True, False])
    assert np.isnan(buffer.mc_returns[:2, 0]).all(), "the truncated episode's returns stay unknown"
    assert buffer.episode_lengths[0] == 0, "Omega is cleared all the same"
    step(buffer, [2, 0], [2, 2])
    step(buffer, [2, 8], [3, 3], dones=[True, True])
    assert np.isnan(buffer.mc_returns[:2, 0]).all()
    # Episode B alone, not chained onto A: G_3 = 2, G_2 = 2 + 0.5 * 2 = 3
    np.testing.assert_allclose(buffer.mc_returns[2:4, 0], [3.0, 2.0])
    # env 1: G_3 = 8, G_2 = 4, G_1 = 2, G_0 = 10 + 0.5 * 2 = 11
    np.testing.assert_allclose(buffer.mc_returns[:4, 1], [11.0, 2.0, 4.0, 8.0])
    # Next actions (Sarsa) are kept within the dropped episode and do not cross into the next one
    assert buffer.next_actions[0, 0] == 1 and buffer.next_actions[1, 0] == -1


def test_dropped_truncation_after_the_ring_wrapped():
    buffer = make_buffer(buffer_size=4)
    buffer.drop_truncated_returns = True
    # A terminated episode of 3 steps, then one of 3 steps truncated: the second overwrites slots 3, 0, 1
    for t in range(3):
        step(buffer, [1.0], [0], dones=[t == 2])
    for t in range(3):
        step(buffer, [5.0], [0], dones=[t == 2], truncated=[t == 2])
    # Slot 2 keeps G_2 = 1 of the first episode; slots 3, 0, 1 hold the dropped one, unknown (not the old returns)
    np.testing.assert_allclose(buffer.mc_returns[2, 0], 1.0)
    assert np.isnan(buffer.mc_returns[[3, 0, 1], 0]).all()


def test_end_open_episodes_with_dropped_truncations_leaves_them_unknown():
    buffer = make_buffer(n_envs=2)
    buffer.drop_truncated_returns = True
    buffer.truncation_value_fn = lambda obs: pytest.fail("a dropped truncation must not be bootstrapped")
    step(buffer, [1, 1], [0, 0])
    step(buffer, [1, 1], [0, 0], dones=[True, False])
    buffer.end_open_episodes()
    np.testing.assert_allclose(buffer.mc_returns[:2, 0], [1.5, 1.0])
    assert np.isnan(buffer.mc_returns[:2, 1]).all()
    # The next episode starts afresh: ended at once, its return is its own reward
    step(buffer, [1, 4], [3, 3], dones=[False, True])
    assert buffer.mc_returns[2, 1] == 4.0 and np.isnan(buffer.mc_returns[:2, 1]).all()


def test_buffer_pickled_before_drop_existed_loads_without_dropping():
    buffer = make_buffer()
    state = buffer.__getstate__()
    del state["drop_truncated_returns"]
    restored = OffOnReplayBuffer.__new__(OffOnReplayBuffer)
    restored.__setstate__(state)
    assert restored.drop_truncated_returns is False


def test_buffer_pickled_before_the_episode_bookkeeping_is_refused_by_name():
    state = make_buffer().__getstate__()
    del state["_n_adds"]
    with pytest.raises(ValueError, match="OffOnReplayBuffer was pickled by an sb3-offon older"):
        OffOnReplayBuffer.__new__(OffOnReplayBuffer).__setstate__(state)


def test_terminated_episode_never_bootstraps():
    buffer = make_buffer()
    buffer.truncation_value_fn = lambda obs: pytest.fail("a terminated episode must not be bootstrapped")
    step(buffer, [1.0], [0])
    step(buffer, [3.0], [2], dones=[True], truncated=[False])
    np.testing.assert_allclose(buffer.mc_returns[:2, 0], [2.5, 3.0])


def test_two_envs_with_different_episode_lengths():
    buffer = make_buffer(n_envs=2)
    buffer.truncation_value_fn = lambda obs: np.asarray(obs).reshape(-1)  # value = the final observation's id
    # env 0: episode A = [1, 1] terminated at step 1, then episode B = [2, 4, 8] truncated at step 4 (final obs 12)
    # env 1: one episode [10, 0, 0, 0, 8] terminated at step 4 (next obs 30, which must not be used)
    step(buffer, [1, 10], [0, 0])
    step(buffer, [1, 0], [1, 1], dones=[True, False])
    step(buffer, [2, 0], [2, 2])
    step(buffer, [4, 0], [3, 3])
    step(buffer, [8, 8], [4, 4], dones=[True, True], truncated=[True, False], next_obs_ids=[12, 30])
    # env 0, episode A: G = [1 + 0.5, 1]; episode B with tail V = 12: G_4 = 8 + 6 = 14, G_3 = 4 + 7 = 11, G_2 = 2 + 5.5
    np.testing.assert_allclose(buffer.mc_returns[:5, 0], [1.5, 1.0, 7.5, 11.0, 14.0])
    # env 1: G_4 = 8, G_3 = 4, G_2 = 2, G_1 = 1, G_0 = 10 + 0.5
    np.testing.assert_allclose(buffer.mc_returns[:5, 1], [10.5, 1.0, 2.0, 4.0, 8.0])


def test_ring_wrap_around_forgets_overwritten_returns():
    buffer = make_buffer(buffer_size=4)
    for reward, done in [(1, False), (1, False), (1, True)]:  # slots 0-2
        step(buffer, [reward], [0], dones=[done])
    np.testing.assert_allclose(buffer.mc_returns[:3, 0], [1.75, 1.5, 1.0])
    step(buffer, [2], [0])  # slot 3
    step(buffer, [3], [0])  # slot 0: overwrites the first transition of the old episode
    assert np.isnan(buffer.mc_returns[0, 0]), "an overwritten slot loses its old return"
    np.testing.assert_allclose(buffer.mc_returns[1:3, 0], [1.5, 1.0])
    step(buffer, [4], [0], dones=[True])  # slot 1: the episode [2, 3, 4] ends in slots 3, 0, 1
    # G = [2 + 0.5 * 5, 3 + 0.5 * 4, 4]: the slots hold the episode in order across the array's end
    np.testing.assert_allclose(buffer.mc_returns[[3, 0, 1], 0], [4.5, 5.0, 4.0])
    np.testing.assert_allclose(buffer.mc_returns[2, 0], 1.0)


def test_episode_longer_than_the_buffer_keeps_correct_returns_in_remaining_slots():
    buffer = make_buffer(buffer_size=4)
    rewards = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    for index, reward in enumerate(rewards):
        step(buffer, [reward], [0], dones=[index == len(rewards) - 1])
    expected = discounted_returns(np.array(rewards), GAMMA)
    # Steps 3..6 are still stored, in slots 3, 0, 1, 2; their returns include the rewards of overwritten steps
    np.testing.assert_allclose(buffer.mc_returns[[3, 0, 1, 2], 0], expected[3:])
    # By hand for the last four: G_6 = 7, G_5 = 9.5, G_4 = 9.75, G_3 = 8.875
    np.testing.assert_allclose(expected[3:], [8.875, 9.75, 9.5, 7.0])


def test_episode_thousands_of_steps_longer_than_the_buffer():
    buffer = make_buffer(buffer_size=8)
    rewards = np.arange(3000, dtype=np.float32) % 7
    for index, reward in enumerate(rewards):
        step(buffer, [reward], [0], dones=[index == len(rewards) - 1])
    expected = discounted_returns(rewards, GAMMA)
    slots = np.arange(3000 - 8, 3000) % 8
    np.testing.assert_allclose(buffer.mc_returns[slots, 0], expected[-8:], rtol=1e-6)


def test_next_actions_within_episodes_and_envs():
    buffer = make_buffer(n_envs=2)
    step(buffer, [0, 0], [1, 3])
    step(buffer, [0, 0], [2, 4], dones=[True, False])
    step(buffer, [0, 0], [0, 1])
    # env 0: slot 0 -> action 2 taken next; slot 1 ended the episode -> unknown; slot 2 is the newest -> unknown
    np.testing.assert_array_equal(buffer.next_actions[:3, 0], [2, -1, -1])
    # env 1: one running episode: next actions 4 and 1, the newest unknown
    np.testing.assert_array_equal(buffer.next_actions[:3, 1], [4, 1, -1])


def test_next_action_of_overwritten_slot_is_reset():
    buffer = make_buffer(buffer_size=3)
    for action in [1, 2, 3]:
        step(buffer, [0], [action])
    np.testing.assert_array_equal(buffer.next_actions[:, 0], [2, 3, -1])
    step(buffer, [0], [4], dones=[True])  # slot 0 overwritten by the last step of the episode
    np.testing.assert_array_equal(buffer.next_actions[:, 0], [-1, 3, 4])


def test_n_step_next_action_is_taken_at_the_nth_next_state():
    buffer = make_buffer(buffer_class=OffOnNStepReplayBuffer, n_steps=3)
    # one episode of 5 steps with actions 0..4, terminated; then a running episode of 2 steps
    for action in range(5):
        step(buffer, [0], [action], dones=[action == 4])
    step(buffer, [0], [1])
    step(buffer, [0], [2])
    next_actions = buffer._sarsa_next_actions(np.arange(7), np.zeros(7, dtype=int))
    # t=0: action at s_3 = 3; t=1: action at s_4 = 4; t>=2: the episode ends within 3 steps -> unknown;
    # t=5: window reaches the newest step -> unknown
    np.testing.assert_array_equal(next_actions, [3, 4, -1, -1, -1, -1, -1])


def test_n_step_next_action_window_across_the_end_of_the_array():
    buffer = make_buffer(buffer_size=4, buffer_class=OffOnNStepReplayBuffer, n_steps=2)
    # One running episode of 6 steps with actions t % 5: steps 2..5 are held, in slots 2, 3, 0, 1 (slot 1 the newest)
    for t in range(6):
        step(buffer, [0], [t % 5])
    next_actions = buffer._sarsa_next_actions(np.arange(4), np.zeros(4, dtype=int))
    # slot 2 (step 2): action at step 4 = 4; slot 3 (step 3): its window goes on in slot 0, action at step 5 = 0;
    # slot 0 (step 4): step 6 is not there yet -> unknown; slot 1 (step 5): the newest -> unknown. The window never
    # runs from the newest slot into the oldest
    np.testing.assert_array_equal(next_actions, [-1, -1, 4, 0])


@pytest.mark.parametrize("n_adds", [50, 137], ids=["full", "wrapped-twice"])
def test_samples_carry_returns_and_next_actions_of_their_own_slot_and_env(n_adds):
    """Three envs with random episode ends, checked against an independent per-step record of every episode."""
    n_envs, buffer_size = 3, 50
    buffer = make_buffer(buffer_size=buffer_size, n_envs=n_envs)
    rng = np.random.default_rng(0)
    returns_by_step = np.full((n_adds, n_envs), np.nan)
    next_by_step = np.full((n_adds, n_envs), -1)
    episodes = [[] for _ in range(n_envs)]
    for t in range(n_adds):
        rewards = rng.integers(0, 5, n_envs).astype(np.float32)
        actions = rng.integers(0, 5, n_envs)
        dones = rng.random(n_envs) < 0.2
        for env in range(n_envs):
            if episodes[env]:
                next_by_step[episodes[env][-1][0], env] = actions[env]
            episodes[env].append((t, rewards[env]))
            if dones[env]:
                steps, episode_rewards = zip(*episodes[env], strict=True)
                returns_by_step[list(steps), env] = discounted_returns(np.array(episode_rewards), GAMMA)
                episodes[env] = []
        # The observation's id names its step and env, which are what the expected values are looked up by
        step(buffer, rewards, actions, dones=dones, obs_ids=t * 10 + np.arange(n_envs))
    # Slot t % buffer_size holds the latest step t written there; returns of episodes that began in overwritten
    # steps still count their rewards
    held = np.arange(max(0, n_adds - buffer_size), n_adds)
    expected_returns = np.full((buffer_size, n_envs), np.nan)
    expected_next = np.full((buffer_size, n_envs), -1)
    expected_returns[held % buffer_size] = returns_by_step[held]
    expected_next[held % buffer_size] = next_by_step[held]
    np.testing.assert_allclose(buffer.mc_returns, expected_returns, rtol=1e-6)
    np.testing.assert_array_equal(buffer.next_actions, expected_next)
    if n_adds > buffer_size:
        assert np.isfinite(expected_returns).sum() > 50 and (expected_next >= 0).sum() > 50

    samples = buffer.sample(500)
    ids = samples.observations.numpy().reshape(-1).astype(int)
    steps, envs = ids // 10, ids % 10
    assert (steps >= held[0]).all(), "only held steps are sampled"
    np.testing.assert_allclose(samples.mc_returns.numpy().reshape(-1), returns_by_step[steps, envs], rtol=1e-6)
    np.testing.assert_array_equal(samples.next_actions.numpy().reshape(-1), next_by_step[steps, envs])
    assert samples.mc_returns.shape == (500, 1) and samples.next_actions.shape == (500, 1)
    assert samples.discounts is None


def test_sampling_moves_the_global_rng_as_sb3_does():
    from stable_baselines3.common.buffers import ReplayBuffer

    plain = ReplayBuffer(64, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=2)
    ours = make_buffer(buffer_size=32, n_envs=2)
    for t in range(40):
        for buffer in (plain, ours):
            obs = np.array([[t], [t + 0.5]], np.float32)
            buffer.add(obs, obs + 1, np.array([[0], [1]]), np.ones(2, np.float32), np.zeros(2), [{}, {}])
    np.random.seed(3)
    plain_samples = plain.sample(32)
    state_after_plain = np.random.get_state()[1].copy()
    np.random.seed(3)
    our_samples = ours.sample(32)
    np.testing.assert_array_equal(np.random.get_state()[1], state_after_plain)
    np.testing.assert_array_equal(plain_samples.observations.numpy(), our_samples.observations.numpy())


@pytest.mark.parametrize(
    "buffer_class, kwargs",
    [
        (OffOnReplayBuffer, {}),
        (OffOnReplayBuffer, {"optimize_memory_usage": True, "handle_timeout_termination": False}),
        (OffOnNStepReplayBuffer, {"n_steps": 3}),
    ],
)
def test_samples_do_not_change_when_the_buffer_does(buffer_class, kwargs):
    # Sampled tensors share memory with the arrays that sampling made (to_torch): never with the buffer's storage
    buffer = make_buffer(buffer_size=8, buffer_class=buffer_class, **kwargs)
    for t in range(12):
        step(buffer, [t], [t % 5], dones=[t % 4 == 3], obs_ids=[t], next_obs_ids=[t + 0.5])
    samples = buffer.sample(16)
    kept = [None if value is None else value.clone() for value in samples]
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts", "mc_returns", "next_actions"):
        storage = getattr(buffer, name, None)
        if storage is not None:
            storage[...] = 3
    for before, after in zip(kept, samples, strict=True):
        if before is not None:
            assert th.equal(before, after)


def test_end_open_episodes_bootstraps_from_the_last_next_observation():
    buffer = make_buffer(n_envs=2)
    buffer.truncation_value_fn = lambda obs: np.asarray(obs).reshape(-1)  # value = the observation id
    step(buffer, [1, 1], [0, 0], next_obs_ids=[5, 6])
    step(buffer, [1, 1], [0, 0], dones=[True, False], next_obs_ids=[7, 8])
    buffer.end_open_episodes()
    np.testing.assert_allclose(buffer.mc_returns[:2, 0], [1.5, 1.0])
    # env 1 was cut at next observation 8: G_1 = 1 + 0.5 * 8 = 5, G_0 = 1 + 0.5 * 5 = 3.5
    np.testing.assert_allclose(buffer.mc_returns[:2, 1], [3.5, 5.0])
    assert buffer.next_actions[1, 1] == -1
    # The next add starts a new episode: it does not chain onto the cut one
    step(buffer, [1, 1], [3, 3])
    assert buffer.next_actions[1, 1] == -1


def test_end_open_episodes_with_optimize_memory_usage():
    buffer = make_buffer(optimize_memory_usage=True, handle_timeout_termination=False)
    buffer.truncation_value_fn = lambda obs: np.asarray(obs).reshape(-1)
    step(buffer, [1], [0], next_obs_ids=[5])
    step(buffer, [1], [0], next_obs_ids=[6])
    buffer.end_open_episodes()
    np.testing.assert_allclose(buffer.mc_returns[:2, 0], [1 + 0.5 * (1 + 0.5 * 6), 1 + 0.5 * 6])


def test_end_open_episodes_stops_the_n_step_window_at_the_cut():
    # Episode A (rewards 1, 2) is cut by a reset after next observation 12; episode B (rewards 100, 100) terminates.
    # A's last n-step target must be 2 + 0.5 * V(12), not 2 + 0.5 * 100 + 0.25 * 100 from B's rewards
    buffer = make_buffer(buffer_class=OffOnNStepReplayBuffer, n_steps=3)
    step(buffer, [1], [0], obs_ids=[10], next_obs_ids=[11])
    step(buffer, [2], [0], obs_ids=[11], next_obs_ids=[12])
    buffer.end_open_episodes()
    assert not buffer.dones[1, 0], "left as stored until a transition follows it"
    step(buffer, [100], [0], obs_ids=[40], next_obs_ids=[41])
    assert buffer.dones[1, 0] and buffer.timeouts[1, 0], "stored as SB3 stores a time-limit truncation"
    step(buffer, [100], [0], dones=[True], obs_ids=[41], next_obs_ids=[42])
    samples = buffer._get_samples(np.array([0, 1]))
    np.testing.assert_allclose(samples.rewards.reshape(-1), [1 + 0.5 * 2, 2])
    np.testing.assert_allclose(samples.next_observations.reshape(-1), [12, 12])
    np.testing.assert_allclose(samples.discounts.reshape(-1), [0.25, 0.5])
    np.testing.assert_allclose(samples.dones.reshape(-1), [0, 0])  # truncation: the target bootstraps
    inputs = buffer.lambda_inputs(np.array([1]), np.array([0]), GAMMA)
    np.testing.assert_allclose(inputs["rewards"], [2])
    np.testing.assert_allclose(inputs["discounts"], [0.5])


def test_end_open_episodes_leaves_finished_episodes_flags_alone():
    buffer = make_buffer(n_envs=2)
    step(buffer, [1, 1], [0, 0], dones=[True, False])
    buffer.end_open_episodes()
    step(buffer, [1, 1], [0, 0])
    assert buffer.dones[0].tolist() == [True, True]
    assert buffer.timeouts[0].tolist() == [False, True], "env 0 terminated: it is not made a truncation"


def test_pickle_drops_the_value_function_and_keeps_open_episodes():
    buffer = make_buffer()
    buffer.truncation_value_fn = lambda obs: np.zeros(len(obs))
    step(buffer, [1], [0])
    step(buffer, [1], [2], dones=[True])
    step(buffer, [2], [3])
    restored = pickle.loads(pickle.dumps(buffer))
    assert restored.truncation_value_fn is None
    assert buffer.truncation_value_fn is not None, "pickling must not change the live buffer"
    np.testing.assert_allclose(restored.mc_returns[:2, 0], [1.5, 1.0])
    # The open episode (one step, reward 2) continues after unpickling
    step(restored, [4], [1], dones=[True])
    np.testing.assert_allclose(restored.mc_returns[2:4, 0], [4.0, 4.0])
    assert restored.next_actions[2, 0] == 1


def test_reset_forgets_everything():
    buffer = make_buffer()
    step(buffer, [1], [0])
    step(buffer, [1], [0], dones=[True])
    step(buffer, [1], [0])
    buffer.reset()
    assert np.isnan(buffer.mc_returns).all() and (buffer.next_actions == -1).all()
    assert buffer.episode_lengths.sum() == 0 and buffer.pos == 0


def test_dict_buffer_records_returns_and_next_actions():
    obs_space = spaces.Dict({"a": OBS_SPACE, "b": spaces.Box(0, 1, shape=(2,), dtype=np.float32)})
    buffer = OffOnDictReplayBuffer(10, obs_space, ACTION_SPACE, device="cpu", n_envs=1, gamma=GAMMA)
    finals = []
    buffer.truncation_value_fn = lambda obs: finals.append(obs) or np.full(len(obs["a"]), 2.0)

    def obs(value):
        return {"a": np.full((1, 1), value, np.float32), "b": np.zeros((1, 2), np.float32)}

    buffer.add(obs(0), obs(1), np.array([[1]]), np.array([1.0], np.float32), np.array([False]), [{}])
    buffer.add(obs(1), obs(2), np.array([[2]]), np.array([1.0], np.float32), np.array([True]), [{"TimeLimit.truncated": True}])
    # G_1 = 1 + 0.5 * 2 = 2, G_0 = 1 + 0.5 * 2 = 2
    np.testing.assert_allclose(buffer.mc_returns[:2, 0], [2.0, 2.0])
    assert finals[0]["a"].reshape(-1).tolist() == [2.0]
    np.testing.assert_array_equal(buffer.next_actions[:2, 0], [2, -1])
    samples = buffer.sample(4)
    assert set(samples.observations) == {"a", "b"}
    np.testing.assert_allclose(samples.mc_returns.numpy(), 2.0)
