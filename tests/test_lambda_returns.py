"""mc_mixing="lambda": lambda-returns checked against hand-computed values and a literal transcription of the formula."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.envs import FakeImageEnv
from stable_baselines3.common.logger import KVWriter, Logger
from stable_baselines3.common.vec_env import VecNormalize

from sb3_offon import OffOnDQN, OffOnReplayBuffer
from sb3_offon.common import lambda_refresh
from sb3_offon.common.buffers import discounted_returns
from sb3_offon.common.lambda_layout import choose_blocks
from sb3_offon.common.lambda_returns import backward_recurrence, compute_lambda_returns
from sb3_offon.offon_dqn import lambda_training

OBS_SPACE = spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float32)
N_ACTIONS = 5
GAMMA, LAM = 0.5, 0.5
LAMBDA = dict(mc_mixing="lambda", mc_initial_prob=0.9, mc_final_prob=0.9, qlearning_initial_prob=1.0, qlearning_final_prob=1.0)
SMALL = dict(learning_starts=50, batch_size=16, train_freq=4, target_update_interval=20, policy_kwargs=dict(net_arch=[16]))


def make_buffer(buffer_size=16, n_envs=1, **kwargs):
    return OffOnReplayBuffer(
        buffer_size * n_envs, OBS_SPACE, spaces.Discrete(N_ACTIONS), device="cpu", n_envs=n_envs, gamma=GAMMA, **kwargs
    )


def step(buffer, rewards, actions, next_obs_ids, dones=None, truncated=None):
    """One transition per env; the next observation is an id that the fake target network below maps to its values."""
    n_envs = buffer.n_envs
    dones = np.zeros(n_envs, dtype=bool) if dones is None else np.asarray(dones, dtype=bool)
    truncated = np.zeros(n_envs, dtype=bool) if truncated is None else np.asarray(truncated, dtype=bool)
    next_obs = np.asarray(next_obs_ids, np.float32).reshape(n_envs, 1)
    infos = [{"TimeLimit.truncated": bool(truncated[i])} if dones[i] else {} for i in range(n_envs)]
    buffer.add(next_obs - 1, next_obs, np.asarray(actions).reshape(n_envs, 1), np.asarray(rewards, np.float32), dones, infos)


def fake_target(next_observations):
    """V(s) = the observation's id, argmax_a Q(s, a) = id % 5."""
    ids = np.asarray(next_observations).reshape(-1)
    return ids.astype(np.float32), ids.astype(np.int64) % N_ACTIONS


def cache_of(buffer, lam=LAM, qlearning_prob=1.0, cut_is_terminal=False, n_wanted=10**9, block_size=100, gamma=GAMMA):
    return compute_lambda_returns(
        buffer, fake_target, n_wanted, block_size, gamma, lam, qlearning_prob, cut_is_terminal, key=0
    )


def returns_by_slot(cache, env=0):
    order = np.argsort(cache.slots[cache.envs == env])
    return cache.returns[cache.envs == env][order]


def reference_lambda_returns(buffer, target, gamma, lam, qlearning_prob, cut_is_terminal=False, block_ends=()):
    """
    The issue's formula, transcribed literally: per env, from the newest stored transition back to the oldest.

    :param block_ends: (chronological index, env) pairs after which the trace is cut as at a block's end
    :return: {(slot, env): G}
    """
    oldest, n_stored, first = buffer.chronology()
    newest_slot = (buffer.pos - 1) % buffer.buffer_size
    returns = {}
    for env in range(buffer.n_envs):
        following = None
        for index in reversed(range(first, n_stored)):
            slot = (oldest + index) % buffer.buffer_size
            reward = float(buffer.rewards[slot, env])
            next_obs = (
                buffer.observations[(slot + 1) % buffer.buffer_size, env]
                if buffer.optimize_memory_usage
                else (buffer.next_observations[slot, env])
            )
            value, greedy = (float(x[0]) for x in target(next_obs[None]))
            next_action = int(buffer.next_actions[slot, env])
            terminated = buffer.dones[slot, env] and not buffer.timeouts[slot, env]
            running_newest = slot == newest_slot and buffer.episode_starts[env] < buffer._n_adds
            if terminated:
                g = reward
            elif next_action < 0 or (index, env) in block_ends:
                cut_without_value = cut_is_terminal and next_action < 0 and not running_newest
                g = reward + gamma * (0.0 if cut_without_value else value)
            else:
                c = 1.0 if next_action == greedy else 1.0 - qlearning_prob
                g = reward + gamma * ((1 - lam * c) * value + lam * c * following)
            returns[(slot, env)] = g
            following = g
    return returns


def assert_matches_reference(cache, reference):
    assert len(cache) == len(reference)
    for slot, env, value in zip(cache.slots, cache.envs, cache.returns, strict=True):
        assert value == pytest.approx(reference[(int(slot), int(env))], rel=1e-6, abs=1e-6), (slot, env)


def three_steps(buffer, actions=(0, 1, 2), dones=None, truncated=None):
    """Rewards 1, 2, 3 at next states 11, 12, 13 (greedy actions 1, 2, 3)."""
    step(buffer, [1.0], [actions[0]], [11])
    step(buffer, [2.0], [actions[1]], [12])
    step(buffer, [3.0], [actions[2]], [13], dones=dones, truncated=truncated)


# --- the recursion ------------------------------------------------------------------------------------------------


def test_backward_recurrence_matches_a_loop():
    rng = np.random.default_rng(0)
    for length in (1, 2, 3, 7, 64, 100, 1000):
        inputs = rng.normal(size=(3, length))
        coefficients = rng.uniform(0, 1, size=(3, length)) * (rng.uniform(size=(3, length)) > 0.1)  # some cuts
        expected = np.zeros_like(inputs)
        following = np.zeros(3)
        for t in reversed(range(length)):
            following = inputs[:, t] + coefficients[:, t] * following
            expected[:, t] = following
        np.testing.assert_allclose(backward_recurrence(inputs, coefficients), expected, rtol=1e-12, atol=1e-12)


# --- hand-computed returns ------------------------------------------------------------------------------------------


def test_terminated_episode_by_hand():
    buffer = make_buffer()
    three_steps(buffer, dones=[True])
    # G_2 = 3; G_1 = 2 + 0.5 * (0.5 * 12 + 0.5 * 3) = 5.75; G_0 = 1 + 0.5 * (0.5 * 11 + 0.5 * 5.75) = 5.1875
    np.testing.assert_allclose(returns_by_slot(cache_of(buffer)), [5.1875, 5.75, 3.0])


@pytest.mark.parametrize("mc_truncation_terminal", [False, True])
def test_truncated_episode_by_hand(mc_truncation_terminal):
    buffer = make_buffer()
    three_steps(buffer, dones=[True], truncated=[True])
    returns = returns_by_slot(cache_of(buffer, cut_is_terminal=mc_truncation_terminal))
    if mc_truncation_terminal:
        np.testing.assert_allclose(returns, [5.1875, 5.75, 3.0])  # as if terminated
    else:
        # G_2 = 3 + 0.5 * 13 = 9.5; G_1 = 2 + 0.5 * (6 + 4.75) = 7.375; G_0 = 1 + 0.5 * (5.5 + 3.6875) = 5.59375
        np.testing.assert_allclose(returns, [5.59375, 7.375, 9.5])


@pytest.mark.parametrize("cut_is_terminal", [False, True])
def test_running_episode_bootstraps_its_newest_transition(cut_is_terminal):
    buffer = make_buffer()
    three_steps(buffer)
    np.testing.assert_allclose(returns_by_slot(cache_of(buffer, cut_is_terminal=cut_is_terminal)), [5.59375, 7.375, 9.5])


def test_an_episode_cut_by_a_reset_is_a_truncation():
    buffer = make_buffer()
    three_steps(buffer)
    buffer.end_open_episodes()  # a new learn() reset the env
    step(buffer, [5.0], [0], [21], dones=[True])  # the next episode does not chain into the cut one
    np.testing.assert_allclose(returns_by_slot(cache_of(buffer)), [5.59375, 7.375, 9.5, 5.0])
    np.testing.assert_allclose(returns_by_slot(cache_of(buffer, cut_is_terminal=True)), [5.1875, 5.75, 3.0, 5.0])


@pytest.mark.parametrize(
    "qlearning_prob, expected_g0",
    [
        (1.0, 1 + 0.5 * 11),  # Watkins: the trace is cut after the non-greedy a_1 = 4 (greedy at s_1 is 1)
        (0.0, 5.1875),  # Peng: not cut at all
        (0.5, 1 + 0.5 * ((1 - 0.25) * 11 + 0.25 * 5.75)),  # c_1 = 0.5
    ],
)
def test_trace_cut_at_a_non_greedy_action(qlearning_prob, expected_g0):
    buffer = make_buffer()
    three_steps(buffer, actions=(0, 4, 2), dones=[True])
    cache = cache_of(buffer, qlearning_prob=qlearning_prob)
    np.testing.assert_allclose(returns_by_slot(cache), [expected_g0, 5.75, 3.0])
    assert cache.trace_cut_fraction == (0.0 if qlearning_prob == 0.0 else 0.5)  # 1 of the 2 continuations


def test_lambda_0_is_the_one_step_target_and_lambda_1_peng_is_the_monte_carlo_return():
    buffer = make_buffer()
    three_steps(buffer, actions=(0, 4, 2), dones=[True])
    step(buffer, [1.0], [3], [31])
    step(buffer, [-2.0], [0], [32], dones=[True], truncated=[True])
    np.testing.assert_allclose(returns_by_slot(cache_of(buffer, lam=0.0)), [1 + 5.5, 2 + 6, 3, 1 + 15.5, -2 + 16])
    monte_carlo = np.concatenate(
        [discounted_returns(np.array([1.0, 2.0, 3.0]), GAMMA), discounted_returns(np.array([1.0, -2.0]), GAMMA, 32.0)]
    )
    np.testing.assert_allclose(returns_by_slot(cache_of(buffer, lam=1.0, qlearning_prob=0.0)), monte_carlo)


# --- several envs, a ring that wraps, blocks -------------------------------------------------------------------------


def random_episodes(buffer, n_adds, seed=0):
    """Episodes of random lengths per env, some terminated, some truncated, with random actions and next states."""
    rng = np.random.default_rng(seed)
    n_envs = buffer.n_envs
    for _ in range(n_adds):
        dones = rng.uniform(size=n_envs) < 0.2
        truncated = dones & (rng.uniform(size=n_envs) < 0.4)
        actions, next_obs_ids = rng.integers(0, N_ACTIONS, n_envs), rng.integers(0, 50, n_envs)
        step(buffer, rng.normal(size=n_envs), actions, next_obs_ids, dones, truncated)


@pytest.mark.parametrize("n_adds", [9, 40], ids=["partly-filled", "wrapped"])
@pytest.mark.parametrize("qlearning_prob", [1.0, 0.0, 0.3])
@pytest.mark.parametrize("cut_is_terminal", [False, True])
def test_several_envs_and_a_wrapping_ring_match_the_formula(n_adds, qlearning_prob, cut_is_terminal):
    buffer = make_buffer(buffer_size=16, n_envs=3)
    random_episodes(buffer, n_adds)
    cache = cache_of(buffer, lam=0.8, qlearning_prob=qlearning_prob, cut_is_terminal=cut_is_terminal)
    assert_matches_reference(cache, reference_lambda_returns(buffer, fake_target, GAMMA, 0.8, qlearning_prob, cut_is_terminal))


def test_optimize_memory_usage_skips_the_overwritten_oldest_slot():
    buffer = make_buffer(buffer_size=16, optimize_memory_usage=True, handle_timeout_termination=False)
    random_episodes(buffer, 40)
    cache = cache_of(buffer, lam=0.8)
    assert buffer.pos not in cache.slots  # its observation is the newest transition's next observation
    assert_matches_reference(cache, reference_lambda_returns(buffer, fake_target, GAMMA, 0.8, 1.0))


def test_blocks_cut_the_trace_at_their_end_and_hold_each_transition_once():
    buffer = make_buffer(buffer_size=64, n_envs=2)
    random_episodes(buffer, 100, seed=1)
    np.random.seed(3)
    cache = cache_of(buffer, lam=0.8, n_wanted=40, block_size=8)
    assert 40 <= len(cache) < 40 + 8
    pairs = set(zip(cache.slots.tolist(), cache.envs.tolist(), strict=True))
    assert len(pairs) == len(cache), "no transition twice"
    # Each block's last transition is where its trace is cut: the newest of each run of consecutive cached slots
    oldest, _, _ = buffer.chronology()
    chronological = (cache.slots - oldest) % buffer.buffer_size
    block_ends = {
        (int(j), int(e))
        for j, e in zip(chronological, cache.envs, strict=True)
        if (int(j) + 1, int(e)) not in {(int(k), int(f)) for k, f in zip(chronological, cache.envs, strict=True)}
    }
    reference = reference_lambda_returns(buffer, fake_target, GAMMA, 0.8, 1.0, block_ends=block_ends)
    for slot, env, value in zip(cache.slots, cache.envs, cache.returns, strict=True):
        assert value == pytest.approx(reference[(int(slot), int(env))], rel=1e-6, abs=1e-6)


def test_choose_blocks_tiles_the_buffer_in_blocks():
    np.random.seed(0)
    envs, starts, lengths = choose_blocks(n_envs=2, first=1, n_stored=50, block_size=8, n_wanted=30)
    assert lengths.sum() >= 30 and (lengths <= 8).all() and (starts >= 1).all() and (starts + lengths <= 50).all()
    # More wanted than stored: one block per env column, the whole of it
    envs, starts, lengths = choose_blocks(n_envs=2, first=0, n_stored=50, block_size=8, n_wanted=1000)
    assert envs.tolist() == [0, 1] and starts.tolist() == [0, 0] and lengths.tolist() == [50, 50]


def test_draws_skip_transitions_overwritten_since_the_refresh():
    buffer = make_buffer(buffer_size=16)
    random_episodes(buffer, 20)
    cache = cache_of(buffer)
    random_episodes(buffer, 5, seed=7)  # overwrites the 5 oldest cached transitions
    np.random.seed(0)
    entries = cache.draw(40, buffer)
    assert len(entries) == 40
    assert buffer.holds_transition(cache.added_at[entries]).all()
    assert len(set(entries[:11].tolist())) == 11, "one pass over the 11 live entries before any repeats"
    random_episodes(buffer, 16, seed=8)
    assert cache.draw(4, buffer) is None, "nothing cached is still stored"


# --- the model --------------------------------------------------------------------------------------------------------


def model_target(model):
    def target(next_observations):
        with th.no_grad():
            q_values = model.q_net_target(th.as_tensor(np.asarray(next_observations)))
        return q_values.max(dim=1).values.numpy(), q_values.argmax(dim=1).numpy()

    return target


@pytest.mark.parametrize("n_envs", [1, 2])
def test_model_targets_match_the_formula_with_its_target_network(n_envs):
    env = make_vec_env("CartPole-v1", n_envs=n_envs, seed=0)
    model = OffOnDQN("MlpPolicy", env, seed=0, buffer_size=300, gamma=0.9, **SMALL, **LAMBDA)
    model.learn(400)  # the ring wraps; episodes of different lengths per env
    model._lambda_cache = None
    cache = model._refreshed_lambda_cache(10**6)  # more than stored: the whole buffer, one block per env
    reference = reference_lambda_returns(model.replay_buffer, model_target(model), 0.9, model.mc_prob, 1.0)
    assert_matches_reference(cache, reference)
    assert cache.lam == pytest.approx(0.9)


def test_training_regresses_on_the_cached_returns(monkeypatch):
    # Blocks longer than the buffer: each refresh computes the whole of it, so nothing is cut at a block's end
    model = OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, buffer_size=300, lambda_block_size=1000, **SMALL, **LAMBDA)
    model.learn(200)
    model._lambda_cache = None
    seen = []

    def recording_loss(current, targets):
        seen.append(targets.clone())
        return th.nn.functional.smooth_l1_loss(current, targets)

    monkeypatch.setitem(__import__("sb3_offon.offon_dqn.offon_dqn", fromlist=["x"]).LOSS_FUNCTIONS, "huber", recording_loss)
    np.random.seed(1)
    model.train(3, batch_size=16)
    cache = model._lambda_cache
    reference = reference_lambda_returns(model.replay_buffer, model_target(model), model.gamma, 0.9, 1.0)
    targets = th.cat(seen).reshape(-1).numpy()
    assert len(targets) == 48 and len(set(targets.tolist())) > 1
    assert set(targets.tolist()) <= set(cache.returns.tolist())
    assert {round(v, 4) for v in targets.tolist()} <= {round(v, 4) for v in reference.values()}


def test_refresh_follows_the_target_network():
    model = OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, buffer_size=500, **{**SMALL, "target_update_interval": 40}, **LAMBDA)
    model.learn(100)
    first = model._lambda_cache
    assert first is not None
    used = []
    original = model._refreshed_lambda_cache
    model._refreshed_lambda_cache = lambda n: used.append(original(n)) or used[-1]  # type: ignore[method-assign]
    model.learn(160, reset_num_timesteps=False)  # 40 training calls; the target network changes at steps 120, 160, 200, 240
    assert len(used) == 40
    assert used[0] is first, "the target network has not changed since the last call"
    assert len({id(cache) for cache in used}) == 1 + 4, "one refresh per target update"
    model.learn(8)  # a new learn() resets the env: episodes were cut, so the cache is computed afresh
    assert model._lambda_cache is not used[-1]


def test_refresh_interval_in_env_steps():
    model = OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, buffer_size=500, lambda_refresh_interval=100, **SMALL, **LAMBDA)
    model.learn(100)
    keys = set()
    original = model._refreshed_lambda_cache
    model._refreshed_lambda_cache = lambda n: keys.add(original(n).key) or model._lambda_cache  # type: ignore[method-assign]
    model.learn(300, reset_num_timesteps=False)
    assert keys == {1, 2, 3, 4}


@pytest.mark.parametrize("n_envs", [1, 2])
def test_a_whole_buffer_cache_is_outgrown_once_the_buffer_has_doubled(n_envs):
    buffer = make_buffer(buffer_size=16, n_envs=n_envs)
    random_episodes(buffer, 3)
    whole = cache_of(buffer)
    assert whole.whole_buffer and len(whole) == 3 * n_envs
    random_episodes(buffer, 2, seed=1)  # 5 steps per env stored, fewer than twice the 3 cached
    assert not whole.outgrown(buffer)
    random_episodes(buffer, 1, seed=2)  # 6: twice as many
    assert whole.outgrown(buffer)
    np.random.seed(0)
    sampled = cache_of(buffer, n_wanted=2, block_size=2)  # fewer wanted than stored: blocks, not the whole buffer
    assert not sampled.whole_buffer
    random_episodes(buffer, 10, seed=3)
    assert not sampled.outgrown(buffer), "a cache of blocks waits for the next refresh however the buffer grows"
    full = cache_of(buffer)  # 16 steps per env: the ring is full and cannot double any more
    random_episodes(buffer, 40, seed=4)
    assert full.whole_buffer and len(full) == 16 * n_envs and not full.outgrown(buffer)


def test_a_young_buffer_is_not_starved_by_rare_target_updates(monkeypatch):
    # SB3's default target_update_interval: one refresh key for the whole run. Training starts at step 24 (the first
    # rollout end past learning_starts=20); without the growth refresh, all training would be on those 24 transitions.
    model = OffOnDQN(
        "MlpPolicy",
        "CartPole-v1",
        seed=0,
        buffer_size=10_000,
        **{**SMALL, "learning_starts": 20, "target_update_interval": 10_000},
        **LAMBDA,
    )
    computed = []
    original = lambda_training.compute_lambda_returns

    def recording(*args, **kwargs):
        computed.append(original(*args, **kwargs))
        return computed[-1]

    monkeypatch.setattr(lambda_training, "compute_lambda_returns", recording)
    model.learn(200)
    assert [len(cache) for cache in computed] == [24, 48, 96, 192], "afresh each time the buffer has doubled"
    assert all(cache.whole_buffer and cache.key == 0 for cache in computed), "with the same target network"
    assert model._lambda_cache is computed[-1]


def test_cache_size_follows_the_samples_trained_until_the_next_refresh():
    model = OffOnDQN(
        "MlpPolicy",
        "CartPole-v1",
        seed=0,
        buffer_size=10_000,
        learning_starts=100,
        batch_size=8,
        train_freq=4,
        gradient_steps=2,
        target_update_interval=40,
        policy_kwargs=dict(net_arch=[16]),
        **LAMBDA,
    )
    assert model._lambda_samples_per_refresh() == 10 * 2 * 8  # 10 calls of 2 steps of 8 samples per target update
    model.learn(300)
    assert 160 <= len(model._lambda_cache) < 160 + model.lambda_block_size


class RecordingWriter(KVWriter):
    def __init__(self):
        self.records = []

    def write(self, key_values, key_excluded, step=0):
        self.records.append(dict(key_values))


def test_lambda_and_trace_cuts_are_logged():
    model = OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, buffer_size=500, **SMALL, **LAMBDA)
    writer = RecordingWriter()
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    model.learn(300, log_interval=1)
    logged = [record for record in writer.records if "train/lambda" in record]
    assert logged and logged[-1]["train/lambda"] == pytest.approx(0.9)
    assert 0.0 < logged[-1]["train/trace_cut_fraction"] < 1.0  # epsilon-greedy takes some non-greedy actions


@pytest.mark.parametrize(
    "name, value",
    [("lambda_block_size", 0), ("lambda_block_size", 2.5), ("lambda_refresh_interval", 0), ("lambda_block_size", True)],
)
def test_bad_lambda_arguments_name_the_parameter(name, value):
    with pytest.raises(ValueError, match=name):
        OffOnDQN("MlpPolicy", "CartPole-v1", **{name: value}, **LAMBDA)


def test_save_load_and_resume_recompute_the_cache(tmp_path):
    model = OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, buffer_size=500, lambda_block_size=7, **SMALL, **LAMBDA)
    model.learn(200)
    model.save(tmp_path / "model")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = OffOnDQN.load(tmp_path / "model", env=model.get_env())
    assert loaded._lambda_cache is None, "a cache is never saved, never used before it is computed"
    assert (loaded.mc_mixing, loaded.lambda_block_size) == ("lambda", 7)
    loaded.load_replay_buffer(tmp_path / "buffer")
    loaded.learn(100, reset_num_timesteps=False)
    assert loaded._lambda_cache is not None and loaded._n_updates > model._n_updates


def test_dict_observations_and_vecnormalize():
    from stable_baselines3.common.envs import SimpleMultiObsEnv

    model = OffOnDQN("MultiInputPolicy", SimpleMultiObsEnv(random_start=False), seed=0, buffer_size=300, **SMALL, **LAMBDA)
    model.learn(200)
    assert model._lambda_cache is not None and np.isfinite(model._lambda_cache.returns).all()

    env = VecNormalize(make_vec_env("CartPole-v1", n_envs=2, seed=0), gamma=0.9)
    model = OffOnDQN(
        "MlpPolicy",
        env,
        seed=0,
        buffer_size=300,
        gamma=0.9,
        **SMALL,
        **{**LAMBDA, "mc_initial_prob": 0.0, "mc_final_prob": 0.0},
    )
    model.learn(200)
    # lambda = 0: the one-step target of SB3's normalised samples, r + gamma * (1 - d) * max_a Q_target(s', a)
    cache = model._refreshed_lambda_cache(10**6)
    buffer = model.replay_buffer
    rewards = env.normalize_reward(buffer.rewards[cache.slots, cache.envs])
    next_obs = env.normalize_obs(buffer.next_observations[cache.slots, cache.envs])
    values, _ = model_target(model)(next_obs)
    terminated = buffer.dones[cache.slots, cache.envs] * (1 - buffer.timeouts[cache.slots, cache.envs])
    np.testing.assert_allclose(cache.returns, rewards + 0.9 * (1 - terminated) * values, rtol=1e-5, atol=1e-5)


def test_optimize_memory_usage_model_matches_the_formula():
    model = OffOnDQN(
        "MlpPolicy",
        "CartPole-v1",
        seed=0,
        buffer_size=120,
        optimize_memory_usage=True,
        replay_buffer_kwargs=dict(handle_timeout_termination=False),
        **SMALL,
        **LAMBDA,
    )
    model.learn(300)  # the ring wraps twice
    model._lambda_cache = None
    cache = model._refreshed_lambda_cache(10**6)
    assert model.replay_buffer.pos not in cache.slots
    assert_matches_reference(cache, reference_lambda_returns(model.replay_buffer, model_target(model), model.gamma, 0.9, 1.0))


def test_the_refresh_pass_in_chunks_matches_one_pass(monkeypatch):
    model = OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, buffer_size=1000, **SMALL, **LAMBDA)
    model.learn(200)
    assert model._lambda_forward_rows() == lambda_refresh.LAMBDA_FORWARD_ROWS  # 16-byte observations: the rows bound
    observations = model.replay_buffer.next_observations[:150, 0]
    monkeypatch.setattr(lambda_refresh, "LAMBDA_FORWARD_ROWS", 7)  # 22 chunks, the last one of 3 rows
    assert model._lambda_forward_rows() == 7
    values, actions = model._target_values_and_actions(observations)
    with th.no_grad():
        q_values = model.q_net_target(th.as_tensor(observations))
    np.testing.assert_allclose(values, q_values.max(dim=1).values.numpy(), rtol=1e-6)
    np.testing.assert_array_equal(actions, q_values.argmax(dim=1).numpy())
    assert values.shape == actions.shape == (150,)


def test_the_refresh_pass_keeps_image_chunks_small():
    # 4 stacked 84x84 frames are 112,896 bytes as float32: 74 of them fit in LAMBDA_FORWARD_BYTES (8 MiB)
    env = FakeImageEnv(screen_height=84, screen_width=84, n_channels=4, discrete=True, channel_first=True)
    model = OffOnDQN("CnnPolicy", env, buffer_size=100, **LAMBDA)
    assert model._observation_bytes() == 4 * 4 * 84 * 84
    assert model._lambda_forward_rows() == lambda_refresh.LAMBDA_FORWARD_BYTES // (4 * 4 * 84 * 84) == 74
