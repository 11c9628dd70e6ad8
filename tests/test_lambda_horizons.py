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
        np.asarray(samples.next_observations),  # StoredRows: every row at once
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


# ----------------------------------------------------------------------------------------------------------------------
# lambda_horizon: lambda stated as a horizon, for OffOnQRDQN and OffOnDQN
# ----------------------------------------------------------------------------------------------------------------------
def parameters_digest(model) -> bytes:
    return b"".join(parameter.detach().numpy().tobytes() for parameter in model.policy.parameters())


def algo_and_settings(algo: str) -> tuple[type, dict]:
    """The class and the small settings of the tests above (OffOnDQN's without QR-DQN's quantile count)."""
    from sb3_offon import OffOnDQN

    if algo == "offon_qrdqn":
        return OffOnQRDQN, SMALL
    return OffOnDQN, {key: value for key, value in SMALL.items() if key != "policy_kwargs"}


@pytest.mark.parametrize(
    "gamma, n_steps, horizon, expected",
    [
        (0.99, 1, 3, 0.0199 / 0.029701),  # (1 - 0.99^2) / (1 - 0.99^3)
        (0.99, 1, 5, (1 - 0.96059601) / (1 - 0.9509900499)),  # 0.99^4, 0.99^5
        (0.9, 1, 3, 0.19 / 0.271),  # (1 - 0.9^2) / (1 - 0.9^3)
        (0.99, 3, 3, 0.0),  # one window: the 3-step target
        # windows of 2 steps, 3 of them: (1 - g^2) / (1 - g^3) with g = 0.99^2, that is (1 - 0.99^4) / (1 - 0.99^6)
        (0.99, 2, 6, (1 - 0.96059601) / (1 - 0.941480149401)),
    ],
)
@pytest.mark.parametrize("algo", ["offon_qrdqn", "offon_dqn"])
def test_lambda_horizon_is_lambda_for_the_whole_run(algo, gamma, n_steps, horizon, expected):
    algo_class, settings = algo_and_settings(algo)
    model = algo_class("MlpPolicy", "CartPole-v1", gamma=gamma, n_steps=n_steps, lambda_horizon=horizon, **settings)
    assert model.mc_prob == pytest.approx(expected, abs=1e-12)  # before any training
    assert model.mc_schedule(1.0) == model.mc_schedule(0.5) == model.mc_schedule(0.0) == model.mc_prob
    assert model.mc_initial_prob == model.mc_final_prob == 0.9  # the defaults, untouched


@pytest.mark.parametrize("algo", ["offon_qrdqn", "offon_dqn"])
def test_lambda_horizon_trains_as_the_lambda_it_states(algo):
    """The same run, bit for bit, as delta1 = lambda_3 passed as mc_initial_prob and mc_final_prob."""
    algo_class, settings = algo_and_settings(algo)
    lam = lambda_for_horizon(3, 0.99)
    stated = algo_class("MlpPolicy", "CartPole-v1", seed=0, lambda_horizon=3, **settings)
    stated.learn(600)
    direct = algo_class("MlpPolicy", "CartPole-v1", seed=0, mc_initial_prob=lam, mc_final_prob=lam, **settings)
    direct.learn(600)
    assert stated.logger.name_to_value["train/mc_prob"] == pytest.approx(lam, abs=1e-15)
    assert parameters_digest(stated) == parameters_digest(direct)
    # The horizon is not ignored: the one-step target (h = 1, lambda 0) trains otherwise. (Early in a CartPole run,
    # longer horizons, h = 5 say, can leave the same parameters: every error exceeds the Huber loss's 1, whose
    # gradient is then its sign whatever the target.)
    differs = algo_class("MlpPolicy", "CartPole-v1", seed=0, lambda_horizon=1, **settings)
    differs.learn(600)
    assert differs.mc_prob == 0.0 and parameters_digest(differs) != parameters_digest(direct)


def test_lambda_horizon_is_saved_and_can_be_changed_on_load(tmp_path):
    model = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=0, lambda_horizon=3, **SMALL)
    model.learn(200)
    model.save(tmp_path / "model")
    loaded = OffOnQRDQN.load(tmp_path / "model", env=model.get_env())
    assert loaded.lambda_horizon == 3 and loaded.mc_schedule(0.0) == pytest.approx(lambda_for_horizon(3, 0.99))
    longer = OffOnQRDQN.load(tmp_path / "model", env=model.get_env(), lambda_horizon=10)
    longer.learn(100, reset_num_timesteps=False)
    assert longer.logger.name_to_value["train/mc_prob"] == pytest.approx(lambda_for_horizon(10, 0.99))
    # A model saved without it (delta1 as it was) trains on delta1
    plain = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=0, mc_initial_prob=0.5, mc_final_prob=0.5, **SMALL)
    plain.save(tmp_path / "plain")
    assert OffOnQRDQN.load(tmp_path / "plain").mc_schedule(0.0) == 0.5


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(lambda_horizon=3, mc_initial_prob=0.5), "`mc_initial_prob`: `lambda_horizon`"),
        (dict(lambda_horizon=3, mc_final_prob=0.0), "`mc_final_prob`: `lambda_horizon`"),
        (dict(lambda_horizon=3, lambda_choice="median"), "`lambda_horizon`: `lambda_choice` 'median'"),
        (dict(lambda_horizon=2, n_steps=3), r"`lambda_horizon` must be a finite number of env steps, at least `n_steps` \(3"),
        (dict(lambda_horizon=0.5), r"`lambda_horizon` must be a finite number of env steps, at least `n_steps` \(1"),
        (dict(lambda_horizon=float("inf")), "`lambda_horizon` must be a finite number of env steps"),
        (dict(lambda_horizon=3, gamma=1.0), r"`lambda_horizon` needs a discount `gamma` in \(0, 1\)"),
        (dict(lambda_horizon="3"), "`lambda_horizon` must be a real number"),
        (dict(lambda_horizon=True), "`lambda_horizon` must be a real number"),
        (dict(lambda_horizon=float("nan")), "`lambda_horizon` must be a real number"),
    ],
)
@pytest.mark.parametrize("algo", ["offon_qrdqn", "offon_dqn"])
def test_what_lambda_horizon_cannot_do_is_refused_by_name(algo, options, message):
    algo_class, _ = algo_and_settings(algo)
    with pytest.raises(ValueError, match=message):
        algo_class("MlpPolicy", "CartPole-v1", **options)


def test_lambda_horizon_needs_the_lambda_returns_in_offon_dqn():
    from sb3_offon import PAPER_TARGETS, OffOnDQN

    paper = {key: value for key, value in PAPER_TARGETS.items() if key not in ("mc_initial_prob", "mc_final_prob")}
    with pytest.raises(
        ValueError, match="`lambda_horizon` states the lambda of the lambda-returns: it needs `mc_mixing='lambda'`"
    ):
        OffOnDQN("MlpPolicy", "CartPole-v1", lambda_horizon=3, **paper)


def test_lambda_horizon_in_a_subclass_that_passes_delta1_on():
    """A user's subclass whose ``__init__`` takes the rest as ``**kwargs``: delta1's defaults are read from the base."""
    from sb3_offon import OffOnDQN

    class Mine(OffOnDQN):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)

    _, settings = algo_and_settings("offon_dqn")
    assert Mine("MlpPolicy", "CartPole-v1", lambda_horizon=3, **settings).mc_prob == pytest.approx(0.0199 / 0.029701)
    with pytest.raises(ValueError, match="`mc_initial_prob`: `lambda_horizon`"):
        Mine("MlpPolicy", "CartPole-v1", lambda_horizon=3, mc_initial_prob=0.5, **settings)


def test_lambda_horizon_without_the_cache():
    model = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=0, lambda_cache=False, lambda_horizon=3, **SMALL)
    model.learn(400)
    assert model.logger.name_to_value["train/lambda"] == pytest.approx(0.0199 / 0.029701)
    # Horizons drawn with mean about 1 / (1 - 0.67) = 3.0 (fewer at episode ends)
    assert 1.5 < model.logger.name_to_value["train/mean_horizon"] < 4.5


def test_a_model_saved_before_lambda_horizon_existed_loads_and_trains_on_delta1(tmp_path):
    """Its saved data has no ``lambda_horizon``: load() keeps the constructor's None, and delta1 as it was saved."""
    import json
    import zipfile

    model = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=0, mc_initial_prob=0.5, mc_final_prob=0.5, **SMALL)
    model.save(tmp_path / "model")
    # Rewrite the archive's data without the key, as a version without the argument saved it
    with zipfile.ZipFile(tmp_path / "model.zip") as archive:
        files = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(files["data"])
    del data["lambda_horizon"]
    files["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(tmp_path / "old.zip", "w") as archive:
        for name, content in files.items():
            archive.writestr(name, content)
    loaded = OffOnQRDQN.load(tmp_path / "old.zip", env=model.get_env())
    assert loaded.lambda_horizon is None and loaded.mc_schedule(0.0) == 0.5
    loaded.learn(200)
    assert loaded.logger.name_to_value["train/mc_prob"] == 0.5
