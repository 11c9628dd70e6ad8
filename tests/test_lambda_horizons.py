"""
Lambda-returns as horizons: lambda_for_horizon against hand-computed values, the horizons' law, the drawn horizons'
returns against a trajectory log kept apart from the buffer (several envs whose episodes end at different steps,
terminations, truncations, cuts, a ring that wraps, n-step windows), and OffOnQRDQN without the cache: n-step QR-DQN's
own targets at lambda = 0, the checks of what it needs, no read-back per gradient step, save and load.
"""

import numpy as np
import pytest
import torch as th
from test_offon_qrdqn import SMALL, contrib_target_quantiles
from test_train_loop import count_read_backs  # noqa: F401  (a fixture)
from test_trajectory_log import GAMMA, make_buffer, play

from sb3_offon import OffOnQRDQN, PrioritizedOffOnReplayBuffer
from sb3_offon.common.lambda_horizons import draw_horizons, lambda_for_horizon, sample_horizon_returns


def test_lambda_for_horizon_by_hand():
    # (1 - 0.99^2) / (1 - 0.99^3) = 0.0199 / 0.029701
    assert lambda_for_horizon(3, 0.99) == pytest.approx(0.0199 / 0.029701)
    assert lambda_for_horizon(5, 0.99) == pytest.approx(0.80400, abs=1e-5)
    assert lambda_for_horizon(1, 0.99) == 0.0
    # gamma 0.5, n = 2: (1 - 0.5) / (1 - 0.25) = 2/3; its contraction gamma (1 - lam) / (1 - gamma lam) = gamma^2
    lam = lambda_for_horizon(2, 0.5)
    assert lam == pytest.approx(2 / 3) and 0.5 * (1 - lam) / (1 - 0.5 * lam) == pytest.approx(0.25)
    for bad in (dict(n=0.5, gamma=0.99), dict(n=3, gamma=1.0), dict(n=3, gamma=0.0)):
        with pytest.raises(ValueError, match="`n`" if bad["n"] < 1 else "`gamma`"):
            lambda_for_horizon(**bad)


def test_horizons_follow_the_lambda_weights():
    rng = np.random.default_rng(0)
    assert np.array_equal(draw_horizons(rng, 0.0, 5, 4), np.ones(5))
    assert np.array_equal(draw_horizons(rng, 1.0, 5, 4), np.full(5, 4))
    # lam 0.5, longest 3: P(1) = 0.5, P(2) = 0.25, P(3) = 0.25 (the remaining weight on the longest)
    horizons = draw_horizons(rng, 0.5, 200_000, 3)
    shares = np.bincount(horizons, minlength=4)[1:] / len(horizons)
    np.testing.assert_allclose(shares, [0.5, 0.25, 0.25], atol=0.005)


def reference(
    steps: list[dict], t: int, horizon: int, cut_is_terminal: bool, truncation_is_terminal: bool = False
) -> tuple[float, float, float, int]:
    """From the log alone: the horizon's discounted rewards (fewer where the episode or the log ends), the discount of
    the value after it (0 where none follows), the state it bootstraps from and the steps it spans.
    ``truncation_is_terminal``: a buffer with ``optimize_memory_usage`` stores a time-limit truncation as a termination
    (as SB3 does)."""
    rewards, k = 0.0, 0
    while True:
        rewards += GAMMA**k * steps[t + k]["reward"]
        k += 1
        if k == horizon or steps[t + k - 1]["end"] is not None or t + k - 1 == len(steps) - 1:
            break
    last = steps[t + k - 1]
    terminal = ("terminated", "truncated") if truncation_is_terminal else ("terminated",)
    no_value = last["end"] in terminal or (cut_is_terminal and last["end"] is not None)
    return rewards, 0.0 if no_value else GAMMA**k, float(last["next"]), k


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize(
    "n_envs, size, n_adds, n_steps, optimize_memory_usage",
    [
        (3, 16, 9, 1, False),  # the ring filling
        (3, 16, 53, 1, False),  # wrapped three times
        (3, 16, 53, 3, False),  # n-step windows
        (1, 5, 23, 2, False),  # a tiny ring
        (2, 16, 53, 1, True),  # optimize_memory_usage: one slot fewer, truncations stored as terminations
    ],
)
@pytest.mark.parametrize("lam, longest", [(0.0, 100), (0.7, 100), (0.9, 4), (1.0, 6)])
@pytest.mark.parametrize("cut_is_terminal", [False, True])
def test_drawn_horizons_match_the_trajectory_log(
    seed, n_envs, size, n_adds, n_steps, optimize_memory_usage, lam, longest, cut_is_terminal
):
    buffer = make_buffer(n_envs, size, n_steps, optimize_memory_usage)
    # With optimize_memory_usage a cut's next observation is overwritten by the next episode's first (as in SB3): no cuts
    log = play(buffer, n_adds, cuts=not optimize_memory_usage, seed=seed)
    np.random.seed(seed)
    samples = sample_horizon_returns(buffer, 200, 40, lam, longest, GAMMA, cut_is_terminal, np.random.default_rng(seed))
    # The horizons drawn, from a generator in the same state: whole windows, at most the longest
    window_count = max(longest // n_steps, 1)
    drawn = draw_horizons(np.random.default_rng(seed), lam, 200, window_count) * n_steps
    if lam == 0.0:
        assert np.all(drawn == n_steps)
    elif lam == 1.0:
        assert np.all(drawn == window_count * n_steps)
    held = size - (1 if optimize_memory_usage and buffer.full else 0)
    first = n_adds - min(n_adds, held)
    for slot, env, added_at, rewards, discount, next_obs, horizon, wanted in zip(
        samples.slots,
        samples.envs,
        samples.added_at,
        samples.rewards,
        samples.discounts,
        samples.next_observations,
        samples.horizons,
        drawn,
        strict=True,
    ):
        t = int(added_at)
        assert first <= t < n_adds and t % size == slot
        # The drawn horizon, shortened only where the episode or the log ended: its return, discount and state
        expected_rewards, expected_discount, expected_next, steps = reference(
            log[env], t, int(wanted), cut_is_terminal, optimize_memory_usage
        )
        assert horizon == steps
        assert rewards == pytest.approx(expected_rewards, rel=1e-5, abs=1e-5)
        assert discount == pytest.approx(expected_discount, rel=1e-9)
        if expected_discount > 0:  # where no value follows, the state is not read (SB3 stores none with optimize_memory_usage)
            assert float(next_obs[0]) == expected_next


@pytest.mark.parametrize("n_envs", [1, 3])
def test_drawn_as_sb3_draws_its_minibatches(n_envs):
    """The transitions are those that calls of SB3's ``sample()`` would draw, one minibatch after the other (slots, then
    env indices), and the global RNG ends where SB3's sampling leaves it."""
    buffer = make_buffer(n_envs, 16, 1, optimize_memory_usage=False)
    play(buffer, 40, cuts=False, seed=0)
    np.random.seed(7)
    samples = sample_horizon_returns(buffer, 4 * 8, 8, 0.5, 100, GAMMA, False, np.random.default_rng(0))
    after_ours = np.random.get_state(legacy=False)
    np.random.seed(7)
    theirs = buffer.sample_minibatches(4, 8).samples  # the same draws as four calls of sample(8)
    observations, actions = buffer.observations_and_actions(samples.slots, samples.envs)
    np.testing.assert_array_equal(observations, theirs.observations.numpy())
    np.testing.assert_array_equal(actions, theirs.actions.numpy())
    ends = np.random.get_state(legacy=False)["state"]
    assert all(np.array_equal(ends[key], after_ours["state"][key]) for key in ("key", "pos"))


def test_without_the_cache_lambda_zero_is_n_step_qrdqns_target(monkeypatch):
    model = OffOnQRDQN(
        "MlpPolicy", "CartPole-v1", seed=0, n_steps=3, lambda_cache=False, mc_initial_prob=0.0, mc_final_prob=0.0, **SMALL
    )
    model.learn(300)  # terminated episodes and a running one
    model.mc_prob = 0.0
    np.random.seed(1)
    ours = model._horizon_targets(64)
    theirs = contrib_target_quantiles(model, ours.slots, monkeypatch)
    np.testing.assert_allclose(ours.returns.numpy(), theirs.numpy(), rtol=1e-5, atol=1e-5)
    # The same slots as SB3's sample() draws from the same RNG state
    np.random.seed(1)
    assert np.array_equal(ours.slots, np.random.randint(0, model.replay_buffer.pos, size=64))


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(lambda_form="projected"), "`lambda_form`"),
        (dict(qlearning_initial_prob=0.5), "`qlearning_initial_prob`"),
        (dict(qlearning_final_prob=1.0), "`qlearning_initial_prob`, `qlearning_final_prob`"),
        (dict(replay_buffer_class=PrioritizedOffOnReplayBuffer), "`replay_buffer_class`"),
    ],
)
def test_what_the_cache_free_form_cannot_do_is_refused_by_name(options, message):
    with pytest.raises(ValueError, match=message):
        OffOnQRDQN("MlpPolicy", "CartPole-v1", lambda_cache=False, **options, **SMALL)
    with pytest.raises(ValueError, match="`lambda_cache`"):
        OffOnQRDQN("MlpPolicy", "CartPole-v1", lambda_cache="no", **SMALL)


def test_a_prioritised_buffer_loaded_later_is_refused_without_the_cache(tmp_path):
    """The prioritised draw is the cache's: a prioritised buffer loaded into a model without the cache would bring the
    cache back in silence."""
    prioritised = OffOnQRDQN("MlpPolicy", "CartPole-v1", replay_buffer_class=PrioritizedOffOnReplayBuffer, **SMALL)
    prioritised.learn(100)
    prioritised.save_replay_buffer(tmp_path / "buffer")
    model = OffOnQRDQN("MlpPolicy", "CartPole-v1", lambda_cache=False, **SMALL)
    with pytest.raises(ValueError, match="prioritised replay needs the cache"):
        model.load_replay_buffer(tmp_path / "buffer")


@pytest.mark.parametrize("options", [{}, {"double_q": True}, {"n_steps": 3}])
def test_no_read_back_per_gradient_step_without_the_cache(count_read_backs, options):  # noqa: F811
    def read_backs(gradient_steps):
        model = OffOnQRDQN(
            "MlpPolicy", "CartPole-v1", seed=0, gradient_steps=gradient_steps, lambda_cache=False, **{**SMALL, **options}
        )
        model.learn(200)
        before = count_read_backs["n"]
        model.train(gradient_steps, batch_size=16)
        return count_read_backs["n"] - before

    # the call's loss (.item) only: the targets stay on the device
    assert read_backs(4) == read_backs(32) == 1


def test_learns_saves_and_loads_without_the_cache(tmp_path):
    model = OffOnQRDQN(
        "MlpPolicy", "CartPole-v1", seed=0, lambda_cache=False, mc_initial_prob=0.67, mc_final_prob=0.67, **SMALL
    )
    model.learn(400)
    # Horizons drawn with mean about 1 / (1 - 0.67) = 3.0 (fewer at episode ends)
    assert 1.5 < model.logger.name_to_value["train/mean_horizon"] < 4.5
    model.save(tmp_path / "model")
    loaded = OffOnQRDQN.load(tmp_path / "model", env=model.get_env())
    assert loaded.lambda_cache is False and loaded.mc_initial_prob == 0.67
    for ours, theirs in zip(model.policy.parameters(), loaded.policy.parameters(), strict=True):
        assert th.equal(ours, theirs)
    loaded.learn(100, reset_num_timesteps=False)
    assert loaded.num_timesteps == 500 and loaded.logger.name_to_value["train/lambda"] == 0.67
