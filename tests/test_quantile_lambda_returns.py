"""OffOnQRDQN's distributional lambda-returns against hand-computed laws and a literal transcription of the recursion."""

import pickle

import numpy as np
import pytest
from gymnasium import spaces

from sb3_offon import OffOnNStepReplayBuffer, OffOnReplayBuffer
from sb3_offon.common import lambda_layout
from sb3_offon.common.lambda_returns import compute_lambda_returns
from sb3_offon.offon_qrdqn.quantile_lambda_returns import compute_quantile_lambda_returns, project_mixture

OBS_SPACE = spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float32)
N_ACTIONS = 5
GAMMA = 0.5
# Z(s) of the fake target network: the observation's id plus these offsets (mean 0, so its mean is the id)
OFFSETS = np.array([-1.0, 0.25, 0.75])
N_ATOMS = len(OFFSETS)


def make_buffer(buffer_size=16, n_envs=1, n_steps=1):
    if n_steps > 1:
        return OffOnNStepReplayBuffer(
            buffer_size * n_envs,
            OBS_SPACE,
            spaces.Discrete(N_ACTIONS),
            device="cpu",
            n_envs=n_envs,
            gamma=GAMMA,
            n_steps=n_steps,
        )
    return OffOnReplayBuffer(
        buffer_size * n_envs, OBS_SPACE, spaces.Discrete(N_ACTIONS), device="cpu", n_envs=n_envs, gamma=GAMMA
    )


def step(buffer, rewards, actions, next_obs_ids, dones=None, truncated=None):
    """One transition per env; the next observation is an id that the fake target network maps to its quantiles."""
    n_envs = buffer.n_envs
    dones = np.zeros(n_envs, dtype=bool) if dones is None else np.asarray(dones, dtype=bool)
    truncated = np.zeros(n_envs, dtype=bool) if truncated is None else np.asarray(truncated, dtype=bool)
    next_obs = np.asarray(next_obs_ids, np.float32).reshape(n_envs, 1)
    infos = [{"TimeLimit.truncated": bool(truncated[i])} if dones[i] else {} for i in range(n_envs)]
    buffer.add(next_obs - 1, next_obs, np.asarray(actions).reshape(n_envs, 1), np.asarray(rewards, np.float32), dones, infos)


def fake_quantiles(next_observations):
    """Z(s) = id + OFFSETS; the greedy action id % 5."""
    ids = np.asarray(next_observations, dtype=np.float64).reshape(-1)
    return (ids[:, None] + OFFSETS).astype(np.float32), ids.astype(np.int64) % N_ACTIONS


def fake_values(next_observations):
    """The scalar counterpart: V(s) = the mean of Z(s) = id."""
    quantiles, actions = fake_quantiles(next_observations)
    return quantiles.mean(axis=1), actions


def quantile_cache(buffer, lam, form="sampled", qlearning_prob=0.0, cut_is_terminal=False, seed=0, rng=None, block_size=100):
    return compute_quantile_lambda_returns(
        buffer,
        fake_quantiles,
        10**9,
        block_size,
        GAMMA,
        lam,
        qlearning_prob,
        cut_is_terminal,
        key=0,
        form=form,
        rng=rng if rng is not None else np.random.default_rng(seed),
    )


def by_slot(cache, env=0):
    mine = cache.envs == env
    order = np.argsort(cache.slots[mine])
    return cache.returns[mine][order]


def three_steps(buffer, actions=(0, 1, 2), dones=True, truncated=False):
    """Rewards 1, 2, 3 at next states 11, 12, 13 (greedy actions 1, 2, 3); the third step ends the episode."""
    step(buffer, [1.0], [actions[0]], [11])
    step(buffer, [2.0], [actions[1]], [12])
    step(buffer, [3.0], [actions[2]], [13], dones=[dones], truncated=[truncated])


# --- literal transcriptions -----------------------------------------------------------------------------------------


def reference_laws(buffer, lam, qlearning_prob=0.0, cut_is_terminal=False):
    """
    The law of each transition's lambda-return as a list of (value, weight), by the recursion written out: per env,
    from the newest transition back to the oldest (one-step buffer, one block per env).
    """
    oldest, n_stored, first = buffer.chronology()
    newest_slot = (buffer.pos - 1) % buffer.buffer_size
    laws = {}
    for env in range(buffer.n_envs):
        following = None
        for index in reversed(range(first, n_stored)):
            slot = (oldest + index) % buffer.buffer_size
            reward = float(buffer.rewards[slot, env])
            quantiles, greedy = fake_quantiles(buffer.next_observations[slot, env][None])
            bootstrap = [(float(x), 1.0 / N_ATOMS) for x in quantiles[0]]
            next_action = int(buffer.next_actions[slot, env])
            terminated = buffer.dones[slot, env] and not buffer.timeouts[slot, env]
            running_newest = slot == newest_slot and buffer.episode_starts[env] < buffer._n_adds
            if terminated:
                after = [(0.0, 1.0)]
            elif next_action < 0:
                after = [(0.0, 1.0)] if cut_is_terminal and not running_newest else bootstrap
            else:
                c = 1.0 if next_action == int(greedy[0]) else 1.0 - qlearning_prob
                after = [(x, w * (1 - lam * c)) for x, w in bootstrap] + [(x, w * lam * c) for x, w in following]
            law = [(reward + GAMMA * x, w) for x, w in after if w > 0]
            laws[(slot, env)] = law
            following = law
    return laws


def quantile_function(law, tau):
    """min {x : F(x) >= tau} of a list of (value, weight), walked in a plain loop."""
    total = 0.0
    for value, weight in sorted(law):
        total += weight
        if total >= tau - 1e-12:
            return value
    return max(value for value, _ in law)


def projected(law):
    return [quantile_function(law, (2 * i + 1) / (2 * N_ATOMS)) for i in range(N_ATOMS)]


def mixture_weights(law):
    """The law's distinct values (rounded) and their total weights."""
    weights = {}
    for value, weight in law:
        weights[round(value, 6)] = weights.get(round(value, 6), 0.0) + weight
    return weights


# --- lambda = 0 and lambda = 1 ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("form", ["sampled", "projected"])
def test_lambda_zero_is_the_one_step_quantile_target(form):
    buffer = make_buffer()
    three_steps(buffer)
    cache = quantile_cache(buffer, lam=0.0, form=form)
    expected = [
        1.0 + GAMMA * (11 + OFFSETS),
        2.0 + GAMMA * (12 + OFFSETS),
        np.full(N_ATOMS, 3.0),  # terminated: no bootstrap
    ]
    np.testing.assert_allclose(by_slot(cache), expected, rtol=1e-6)


@pytest.mark.parametrize("form", ["sampled", "projected"])
def test_lambda_one_without_cuts_gives_the_monte_carlo_return(form):
    buffer = make_buffer()
    three_steps(buffer, actions=(0, 3, 4))  # non-greedy next actions (greedy: 1 at s_1, 2 at s_2): no cut at delta2 = 0
    cache = quantile_cache(buffer, lam=1.0, form=form)
    returns = [1 + GAMMA * 2 + GAMMA**2 * 3, 2 + GAMMA * 3, 3.0]
    np.testing.assert_allclose(by_slot(cache), np.repeat(np.array(returns)[:, None], N_ATOMS, axis=1), rtol=1e-6)


def test_truncation_bootstraps_from_the_last_state_or_ends_with_zero():
    buffer = make_buffer()
    three_steps(buffer, dones=True, truncated=True)
    bootstrapped = by_slot(quantile_cache(buffer, lam=1.0))
    np.testing.assert_allclose(bootstrapped[2], 3.0 + GAMMA * (13 + OFFSETS), rtol=1e-6)
    np.testing.assert_allclose(bootstrapped[0], 1 + GAMMA * 2 + GAMMA**2 * 3 + GAMMA**3 * (13 + OFFSETS), rtol=1e-6)
    terminal = by_slot(quantile_cache(buffer, lam=1.0, cut_is_terminal=True))
    np.testing.assert_allclose(terminal[2], np.full(N_ATOMS, 3.0), rtol=1e-6)
    np.testing.assert_allclose(terminal[0], np.full(N_ATOMS, 1 + GAMMA * 2 + GAMMA**2 * 3), rtol=1e-6)


def test_a_running_episode_bootstraps_its_newest_transition():
    buffer = make_buffer()
    step(buffer, [1.0], [0], [11])
    step(buffer, [2.0], [1], [12])  # still running
    targets = by_slot(quantile_cache(buffer, lam=1.0, cut_is_terminal=True))
    np.testing.assert_allclose(targets[1], 2.0 + GAMMA * (12 + OFFSETS), rtol=1e-6)
    np.testing.assert_allclose(targets[0], 1.0 + GAMMA * 2.0 + GAMMA**2 * (12 + OFFSETS), rtol=1e-6)


# --- the three-step episode against the exact mixture -----------------------------------------------------------------

LAM = 0.6  # with N = 3, no cumulative weight of the mixtures below equals a quantile level (no ties to break)


def test_the_projected_form_is_the_recursion_with_each_mixture_projected():
    buffer = make_buffer()
    three_steps(buffer, actions=(0, 3, 2))  # at s_1 (id 11) the greedy action is 1: the recorded 3 is cut by delta2
    laws = reference_laws(buffer, LAM, qlearning_prob=0.5)
    # The newest two: one projection of the exact mixture
    targets = by_slot(quantile_cache(buffer, lam=LAM, form="projected", qlearning_prob=0.5))
    np.testing.assert_allclose(targets[2], projected(laws[(2, 0)]), rtol=1e-6)
    np.testing.assert_allclose(targets[1], projected(laws[(1, 0)]), rtol=1e-6)
    # The first: the mixture of Z(s_1) with the projected law of the second, projected again
    c = 0.5  # the next action (3) is not the greedy one at s_1 (1)
    bootstrap = [(11.0 + x, (1 - LAM * c) / N_ATOMS) for x in OFFSETS]
    following = [(x, LAM * c / N_ATOMS) for x in projected(laws[(1, 0)])]
    expected = [1.0 + GAMMA * x for x in projected(bootstrap + following)]
    np.testing.assert_allclose(targets[0], expected, rtol=1e-6)


def test_the_sampled_form_draws_the_exact_mixture():
    """Over many refreshes, the pooled atoms of each transition follow its exact law (fixed seed, 5 sigma)."""
    buffer = make_buffer()
    three_steps(buffer, actions=(0, 3, 2))
    laws = reference_laws(buffer, LAM, qlearning_prob=0.5)
    rng = np.random.default_rng(0)
    n_refreshes = 4000
    pooled = np.stack([by_slot(quantile_cache(buffer, lam=LAM, qlearning_prob=0.5, rng=rng)) for _ in range(n_refreshes)])
    for slot in range(3):
        exact = mixture_weights(laws[(slot, 0)])
        values, counts = np.unique(np.round(pooled[:, slot].astype(np.float64), 4), return_counts=True)
        seen = dict(zip(values.tolist(), (counts / counts.sum()).tolist(), strict=True))
        assert set(seen) <= {round(value, 4) for value in exact}, slot
        for value, weight in exact.items():
            # each refresh draws one horizon: its N atoms come together, so the count is over refreshes
            tolerance = 5 * np.sqrt(weight * (1 - weight) / n_refreshes) + 1e-9
            assert seen.get(round(value, 4), 0.0) == pytest.approx(weight, abs=tolerance), (slot, value)
    # the first transition's law has its three horizons, weights (1 - lam c), lam c (1 - lam), lam c lam
    first = mixture_weights(laws[(0, 0)])
    assert sum(first.values()) == pytest.approx(1.0)
    assert first[round(1 + GAMMA * 2 + GAMMA**2 * 3, 6)] == pytest.approx(LAM * 0.5 * LAM)


def test_the_sampled_mean_is_the_scalar_lambda_return():
    """E[mean of the sampled atoms] = OffOnDQN's lambda-return with V = the mean of Z, on two envs of unequal episodes."""
    buffer = make_buffer(n_envs=2)
    rewards = [[1.0, -1.0], [2.0, 0.5], [3.0, 4.0], [0.5, 1.5], [1.0, 2.0]]
    ends = [[False, True], [False, False], [True, False], [False, True], [False, False]]
    for t, (reward, done) in enumerate(zip(rewards, ends, strict=True)):
        step(buffer, reward, [t % N_ACTIONS, (t + 2) % N_ACTIONS], [20 + t, 30 + t], dones=done)
    scalar = compute_lambda_returns(buffer, fake_values, 10**9, 100, GAMMA, LAM, 0.5, False, key=0)
    rng = np.random.default_rng(1)
    n_refreshes = 3000
    draws = np.stack(
        [quantile_cache(buffer, lam=LAM, qlearning_prob=0.5, rng=rng).returns.mean(axis=1) for _ in range(n_refreshes)]
    )
    standard_error = draws.std(axis=0) / np.sqrt(n_refreshes)
    assert np.all(np.abs(draws.mean(axis=0) - scalar.returns) <= 5 * standard_error + 1e-5)
    assert np.count_nonzero(standard_error) >= 4  # some horizons are random indeed
    # and the projected form matches the literal recursion on both envs
    laws = reference_laws(buffer, LAM, qlearning_prob=0.5)
    projected_cache = quantile_cache(buffer, lam=LAM, form="projected", qlearning_prob=0.5)
    for slot, env, atoms in zip(projected_cache.slots, projected_cache.envs, projected_cache.returns, strict=True):
        if not laws_need_nested_projection(buffer, slot, env):
            np.testing.assert_allclose(atoms, projected(laws[(int(slot), int(env))]), rtol=1e-6)


def laws_need_nested_projection(buffer, slot, env):
    """Whether the transition's trace goes on past its successor (then the projected form projects a projected law)."""
    next_action = int(buffer.next_actions[slot, env])
    if next_action < 0:
        return False
    return int(buffer.next_actions[(slot + 1) % buffer.buffer_size, env]) >= 0


# --- buffers: several envs, a wrapped ring, a reload, n-step windows ---------------------------------------------------


def test_a_wrapped_ring_buffer_gives_the_deterministic_horizons():
    buffer = make_buffer(buffer_size=8)
    rng = np.random.default_rng(3)
    for t in range(21):  # wraps twice; episodes of 5 steps
        step(buffer, [float(rng.integers(-3, 4))], [t % N_ACTIONS], [40 + t], dones=[t % 5 == 4])
    assert buffer.full
    for lam in (0.0, 1.0):
        cache = quantile_cache(buffer, lam=lam)
        laws = reference_laws(buffer, lam)
        for slot, env, atoms in zip(cache.slots, cache.envs, cache.returns, strict=True):
            law = laws[(int(slot), int(env))]
            np.testing.assert_allclose(np.sort(atoms), np.sort([x for x, _ in law] * (N_ATOMS // len(law))), rtol=1e-5)


def test_a_reloaded_buffer_gives_the_same_targets():
    buffer = make_buffer(n_envs=2)
    for t in range(9):
        step(buffer, [float(t), -float(t)], [t % N_ACTIONS, 1], [50 + t, 60 + t], dones=[t == 4, t == 6])
    reloaded = pickle.loads(pickle.dumps(buffer))
    for form in ("sampled", "projected"):
        before = quantile_cache(buffer, lam=LAM, form=form, seed=7)
        after = quantile_cache(reloaded, lam=LAM, form=form, seed=7)
        np.testing.assert_array_equal(before.returns, after.returns)
        np.testing.assert_array_equal(before.slots, after.slots)


def test_n_step_windows_at_lambda_zero_are_the_n_step_target():
    buffer = make_buffer(n_steps=2)
    for t, reward in enumerate([1.0, 2.0, 3.0, 4.0]):
        step(buffer, [reward], [0], [70 + t], dones=[t == 3])
    targets = by_slot(quantile_cache(buffer, lam=0.0))
    np.testing.assert_allclose(targets[0], 1 + GAMMA * 2 + GAMMA**2 * (71 + OFFSETS), rtol=1e-6)
    np.testing.assert_allclose(targets[2], np.full(N_ATOMS, 3 + GAMMA * 4), rtol=1e-6)  # the window ends the episode
    targets = by_slot(quantile_cache(buffer, lam=1.0))
    np.testing.assert_allclose(targets[0], np.full(N_ATOMS, 1 + GAMMA * 2 + GAMMA**2 * 3 + GAMMA**3 * 4), rtol=1e-6)


def test_project_mixture_is_the_quantile_function_of_the_mixture():
    rng = np.random.default_rng(0)
    first, second = rng.normal(size=(6, 4)), rng.normal(size=(6, 4))
    weights = rng.uniform(0.05, 0.95, size=6)
    result = project_mixture(first, weights, second, 1 - weights)
    for row in range(6):
        law = [(x, weights[row] / 4) for x in first[row]] + [(x, (1 - weights[row]) / 4) for x in second[row]]
        expected = [quantile_function(law, (2 * i + 1) / 8) for i in range(4)]
        np.testing.assert_allclose(result[row], expected)


# --- every sampled target against a log of the steps as they were taken ------------------------------------------------


def logged_random_steps(buffer, n_adds, seed, cut_at=None):
    """
    ``n_adds`` random steps per env (terminations and truncations at random, ``end_open_episodes`` before step
    ``cut_at``), each also written to a log of its own, per env and in the order taken: the reference below reads the
    log, never the buffer.
    """
    rng = np.random.default_rng(seed)
    log = [[] for _ in range(buffer.n_envs)]
    for index in range(n_adds):
        if index == cut_at:
            buffer.end_open_episodes()
            for env_log in log:
                if env_log:
                    env_log[-1]["ended"] = True
        rewards = rng.integers(-5, 6, buffer.n_envs) + rng.random(buffer.n_envs)
        actions = rng.integers(0, N_ACTIONS, buffer.n_envs)
        draws = rng.random(buffer.n_envs)
        terminated, truncated = draws < 0.12, (draws >= 0.12) & (draws < 0.22)
        next_ids = 100 + index * buffer.n_envs + np.arange(buffer.n_envs)
        step(buffer, rewards, actions, next_ids, dones=terminated | truncated, truncated=truncated)
        for env, env_log in enumerate(log):
            ended = bool(terminated[env] or truncated[env])
            reward, action, next_id = float(np.float32(rewards[env])), int(actions[env]), float(next_ids[env])
            env_log.append(dict(reward=reward, action=action, next_id=next_id, terminated=bool(terminated[env]), ended=ended))
    return log


def logged_horizons(env_log, start, block_end, n_steps, lam, qlearning_prob, cut_is_terminal):
    """
    Every horizon of the lambda-return of the transition taken at ``start`` (an index into ``env_log``), as (k-step
    law's N atoms, weight), from the log: windows of up to ``n_steps`` steps that stop at an episode's end or at the
    newest step; the trace goes on past a full window whose next window starts within the block (``block_end``, the
    block's last index), with weight lam c (c = 1 after the greedy action, 1 - delta2 after another).
    """
    discounted, k, end = 0.0, 0, start
    for end in range(start, start + n_steps):
        discounted += GAMMA**k * env_log[end]["reward"]
        k += 1
        if env_log[end]["ended"] or end == len(env_log) - 1:
            break
    last = env_log[end]
    bootstrap = last["next_id"] + OFFSETS
    goes_on = k == n_steps and not last["ended"] and end + 1 < len(env_log) and start + n_steps <= block_end
    if goes_on:
        greedy = int(last["next_id"]) % N_ACTIONS
        weight = lam * (1.0 if env_log[start + n_steps]["action"] == greedy else 1.0 - qlearning_prob)
        following = logged_horizons(env_log, start + n_steps, block_end, n_steps, lam, qlearning_prob, cut_is_terminal)
        after = [(bootstrap, 1.0 - weight)] + [(atoms, w * weight) for atoms, w in following]
    elif last["terminated"] or (cut_is_terminal and last["ended"]):
        after = [(np.zeros(N_ATOMS), 1.0)]
    else:
        after = [(bootstrap, 1.0)]
    return [(discounted + GAMMA**k * atoms, w) for atoms, w in after if w > 0]


@pytest.mark.parametrize(
    "buffer_size, n_envs, n_steps, n_adds, lam, qlearning_prob, cut_is_terminal, n_wanted, block_size, cut_at",
    [
        (8, 1, 1, 21, 0.6, 0.5, False, 10**9, 100, None),  # wrapped twice, one env, whole buffer
        (7, 3, 1, 25, 0.8, 1.0, True, 10**9, 100, 12),  # three envs, wrapped, a reset's cut, Watkins's cuts
        (7, 3, 1, 25, 0.6, 0.5, False, 12, 3, None),  # small blocks: traces cut at the blocks' ends
        (9, 2, 2, 30, 0.6, 0.5, False, 10**9, 100, 15),  # 2-step windows, wrapped, a reset's cut
        (10, 3, 3, 33, 0.8, 0.0, True, 15, 4, None),  # 3-step windows in small blocks
        (12, 2, 1, 9, 0.9, 0.0, False, 10**9, 100, 5),  # a buffer not yet full
    ],
)
def test_every_sampled_target_is_one_horizon_of_the_logged_law(
    monkeypatch, buffer_size, n_envs, n_steps, n_adds, lam, qlearning_prob, cut_is_terminal, n_wanted, block_size, cut_at
):
    chosen = []  # the blocks of each refresh: a trace stops at its block's end
    choose_blocks = lambda_layout.choose_blocks

    def recording_choose_blocks(*args):
        chosen.append(choose_blocks(*args))
        return chosen[-1]

    monkeypatch.setattr(lambda_layout, "choose_blocks", recording_choose_blocks)
    buffer = make_buffer(buffer_size, n_envs, n_steps)
    log = logged_random_steps(buffer, n_adds, seed=n_adds, cut_at=cut_at)
    # The blocks (choose_blocks draws from NumPy's global generator): at this seed, in the cases with small blocks, some
    # short block ends where its last transition's trace could have gone on
    np.random.seed(4)
    settings = dict(n_wanted=n_wanted, block_size=block_size, gamma=GAMMA, lam=lam, qlearning_prob=qlearning_prob)
    scalar = compute_lambda_returns(buffer, fake_values, cut_is_terminal=cut_is_terminal, key=0, **settings)
    np.random.seed(4)
    rng = np.random.default_rng(1)
    cache = compute_quantile_lambda_returns(
        buffer, fake_quantiles, cut_is_terminal=cut_is_terminal, key=0, rng=rng, **settings
    )
    np.testing.assert_array_equal(cache.added_at, scalar.added_at)
    block_envs, block_starts, block_lengths = chosen[-1]
    assert len(chosen) == 2 and all((a == b).all() for a, b in zip(chosen[0], chosen[1], strict=True))
    first_added = buffer._n_adds - buffer.chronology()[1]  # the add index of chronological index 0
    block_end = {}
    for env, start, length in zip(block_envs, block_starts, block_lengths, strict=True):
        for index in range(start, start + length):
            block_end[(int(env), first_added + index)] = first_added + start + length - 1

    horizons_drawn = set()
    for env, added_at, atoms, scalar_return in zip(cache.envs, cache.added_at, cache.returns, scalar.returns, strict=True):
        end = block_end[(int(env), int(added_at))]
        law = logged_horizons(log[env], int(added_at), end, n_steps, lam, qlearning_prob, cut_is_terminal)
        # The scalar lambda-return is the law's mean (the fake network's quantiles have the id as their mean)
        assert sum(w * horizon.mean() for horizon, w in law) == pytest.approx(scalar_return, rel=1e-5, abs=1e-4)
        matches = [i for i, (horizon, _) in enumerate(law) if np.allclose(atoms, horizon, rtol=1e-5, atol=1e-4)]
        assert matches, (int(env), int(added_at), atoms, law)
        horizons_drawn.add(matches[0])
    if n_wanted >= n_envs * buffer_size:  # the whole buffer: every stored transition once
        assert len(cache) == n_envs * buffer.chronology()[1]
    assert len(horizons_drawn) > 1  # not only one-step targets: the traces went on
