"""lambda_choice="median": the chosen lambdas and targets against hand-computed values and the fixed-lambda returns."""

import numpy as np
import pandas as pd
import pytest
from stable_baselines3.common.logger import configure
from test_quantile_lambda_returns import GAMMA, fake_quantiles, fake_values, make_buffer, step

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.common.lambda_choice import MEDIAN_GRID, choose_lambda
from sb3_offon.common.lambda_layout import lambda_layout
from sb3_offon.common.lambda_returns import compute_lambda_returns
from sb3_offon.offon_qrdqn import quantile_lambda_returns
from sb3_offon.offon_qrdqn.quantile_lambda_returns import compute_quantile_lambda_returns

SMALL = dict(learning_starts=100, batch_size=16, train_freq=4, target_update_interval=50, policy_kwargs=dict(net_arch=[16]))


def table_target(values):
    """A target network given as a table: V(s) = values[id of s], greedy action 0."""

    def target(next_observations):
        ids = np.asarray(next_observations).reshape(-1).astype(int)
        return np.array([values.get(i, 0.0) for i in ids], dtype=np.float32), np.zeros(len(ids), dtype=np.int64)

    return target


def chain(rewards):
    """One terminated episode with these rewards; its next states have ids 11, 12, ..."""
    buffer = make_buffer(buffer_size=max(16, len(rewards)))
    for i, reward in enumerate(rewards):
        step(buffer, [reward], [0], [11 + i], dones=[i == len(rewards) - 1])
    return buffer


def median_cache(buffer, target, qlearning_prob=0.0, block_size=100, n_wanted=10**9, choice="median", lam=0.9):
    return compute_lambda_returns(
        buffer, target, n_wanted, block_size, GAMMA, lam, qlearning_prob, False, key=0, choice=choice
    )


def by_slot(cache, env=0):
    mine = cache.envs == env
    order = np.argsort(cache.slots[mine])
    return cache.returns[mine][order]


def test_a_critic_off_in_one_direction_gives_the_middle_lambda():
    # Rewards 1, 2, 3 (gamma 0.5), V = 0 everywhere: G^lam_2 = 2 + 1.5 lam, G^lam_1 = 1 + lam + 0.75 lam^2, both
    # increasing in lambda, so the median of the 21 is lambda 0.5's
    cache = median_cache(chain([1.0, 2.0, 3.0]), table_target({}))
    np.testing.assert_allclose(by_slot(cache), [1.6875, 2.75, 3.0])
    assert cache.lam == 0.5 and cache.lambda_spread == 0.0


def test_an_exact_critic_gives_its_own_values():
    # The true values of the chain: after step 1, 2 + 0.5 * 3 = 3.5; after step 2, 3. Every lambda-return is then the
    # true return of the transition, so any lambda gives it; the tie goes to the middle of the grid
    cache = median_cache(chain([1.0, 2.0, 3.0]), table_target({11: 3.5, 12: 3.0}))
    np.testing.assert_allclose(by_slot(cache), [2.75, 3.5, 3.0])
    assert cache.lam == 0.5 and cache.lambda_spread == 0.0


def test_td_errors_of_both_signs_move_the_chosen_lambda():
    # Rewards 0, 0, 8, V(after step 1) = 3, V(after step 2) = -4, gamma 0.5:
    # G_2 = 0.5 [(1 - lam)(-4) + 8 lam] = -2 + 6 lam (increasing: lambda 0.5, G = 1);
    # G_1 = 0.5 [(1 - lam) 3 + lam G_2] = 1.5 - 2.5 lam + 3 lam^2, a parabola whose vertex is at lam = 5/12: on the grid,
    # ordered by value, 0.40, 0.45, 0.35, 0.50, 0.30, 0.55, 0.25, 0.60, 0.20, 0.65, then 0.15, the 11th of 21: the median,
    # 3 * 0.15^2 - 2.5 * 0.15 + 1.5 = 1.1925
    cache = median_cache(chain([0.0, 0.0, 8.0]), table_target({11: 3.0, 12: -4.0}))
    np.testing.assert_allclose(by_slot(cache), [1.1925, 1.0, 8.0], rtol=1e-6)
    # The last transition's trace cannot go on (its lambda does not count): the mean and spread of 0.15 and 0.5
    assert cache.lam == pytest.approx(0.325)
    assert cache.lambda_spread == pytest.approx(0.175)


def test_ties_below_float_resolution_go_to_the_middle():
    # V = 1 everywhere, rewards 0.5 but -0.5 at step 40 (gamma 0.5): every TD error is 0 but step 40's (-1) and the
    # last step's (-0.5: it terminates, 0.5 - 1), so G^lam is monotone in lambda and the median is lambda 0.5's; far
    # from step 40 the weight (0.5 lam)^k falls below float64's resolution, and the small lambdas tie with the median
    rewards = [0.5] * 45
    rewards[39] = -0.5
    cache = median_cache(chain(rewards), table_target({11 + i: 1.0 for i in range(45)}))
    # G^0.5_t = V + sum_k 0.25^k delta_{t+k} = 1 - 0.25^(39 - t) [t <= 39] - 0.5 * 0.25^(44 - t) (t from 0)
    t = np.arange(45)
    expected = 1.0 - np.where(t <= 39, 0.25 ** np.maximum(39 - t, 0), 0.0) - 0.5 * 0.25 ** (44 - t)
    np.testing.assert_allclose(by_slot(cache), expected, rtol=1e-6)
    assert cache.lam == 0.5 and cache.lambda_spread == 0.0


def test_cut_traces_do_not_count_in_the_logged_lambdas():
    # Watkins's cut (delta2 = 1) after the non-greedy action of step 2 (action 1; greedy 0): the trace of step 1 stops
    # there, and lambda does not change its return. The others as in the test above with rewards 0, 0, 8: chosen 0.15
    # and 0.5, so the mean and spread of those two alone
    buffer = make_buffer()
    for i, (reward, action) in enumerate(zip([1.0, 0.0, 0.0, 8.0], [0, 1, 0, 0], strict=True)):
        step(buffer, [reward], [action], [11 + i], dones=[i == 3])
    cache = median_cache(buffer, table_target({12: 3.0, 13: -4.0}), qlearning_prob=1.0)
    assert cache.lam == pytest.approx(0.325) and cache.lambda_spread == pytest.approx(0.175)


def test_a_refresh_where_no_trace_goes_on_logs_the_middle():
    cache = median_cache(chain([1.0]), table_target({}))
    assert cache.lam == 0.5 and cache.lambda_spread == 0.0


def test_persistent_td_errors_give_a_long_horizon():
    # V = 0 at every state the episode visits (the terminal one's 100 is never used), rewards 1, 2, 3, 5, 4,
    # terminated: delta_t = r_t for t >= 1 (V(s_t) = 0, nothing after the last). Pairs (delta_t, delta_t+1) where the
    # trace of t goes on: (2, 3), (3, 5), (5, 4); their correlation: centred x (-4/3, -1/3, 5/3), y (-1, 1, 0):
    # 1 / sqrt(42/9 * 2) = 0.32733
    buffer = chain([1.0, 2.0, 3.0, 5.0, 4.0])
    target = table_target({15: 100.0})
    cache = median_cache(buffer, target, choice="autocorrelation")
    assert cache.lam == pytest.approx(1.0 / np.sqrt(84.0 / 9.0)) and cache.lambda_spread is None
    fixed = compute_lambda_returns(buffer, target, 10**9, 100, GAMMA, cache.lam, 0.0, False, key=0)
    np.testing.assert_array_equal(by_slot(cache), by_slot(fixed))


def test_neighbouring_td_errors_of_n_step_windows():
    # n_steps = 2, V = 0: the TD error of window t is its discounted reward R_t = r_t + 0.5 r_{t+1} (r_t alone for the
    # last, cut short by the termination), defined where window t - 2 precedes it in the episode; pairs (t, t + 2) where
    # the trace of t goes on (window t + 2 exists). Written out here, apart from the layout's arrays
    rewards = [0.0, 1.0, 1.0, 2.0, 3.0, 5.0, 8.0, 6.0, 9.0]
    buffer = make_buffer(buffer_size=16, n_steps=2)
    for i, reward in enumerate(rewards):
        step(buffer, [reward], [0], [11 + i], dones=[i == len(rewards) - 1])
    last = len(rewards) - 1
    windows = [rewards[t] + (GAMMA * rewards[t + 1] if t < last else 0.0) for t in range(len(rewards))]
    pairs = [(windows[t], windows[t + 2]) for t in range(2, last - 1)]
    expected = np.corrcoef(np.array(pairs).T)[0, 1]
    assert 0.0 < expected < 1.0
    cache = median_cache(buffer, table_target({}), choice="autocorrelation")
    assert cache.lam == pytest.approx(expected)


def test_td_errors_across_episodes_and_cut_traces_written_out():
    # n_steps = 2, gamma 0.5, V(s) = a table over the next states' ids, greedy action 0 everywhere and Watkins's cut
    # (delta2 = 1): two episodes in one env, the first terminated at step 5, the second running. Written out per window
    # t: k = min(2, steps left in its episode), R_t = sum_{j<k} 0.5^j r_{t+j}, its next state the one after step
    # t + k - 1 (value 0 if that step terminated), delta_t = R_t + 0.5^k V(next) - V(s_t) where the window t - 2 of
    # the same episode was full (its next state is s_t); pairs (t, t + 2) where window t + 2 is in the episode and the
    # action recorded at its start is greedy (else c = 0)
    rewards = [1.0, -2.0, 0.5, 3.0, 1.0, 2.0, 0.0, 4.0, -1.0, 2.5, 1.5, 0.5, 2.0, -0.5, 3.0, 1.0]
    actions = [0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0]
    ends = {5}
    values = {11 + i: float((7 * i) % 5 - 1.5) for i in range(len(rewards))}
    buffer = make_buffer(buffer_size=16, n_steps=2)
    for i, (reward, action) in enumerate(zip(rewards, actions, strict=True)):
        step(buffer, [reward], [action], [11 + i], dones=[i in ends])
    episodes = [range(0, 6), range(6, len(rewards))]
    errors, pairs = {}, []
    for episode in episodes:
        last = episode[-1]
        last_terminates = last in ends
        for t in episode:
            k = min(2, last - t + 1)
            value = 0.0 if (t + k - 1 == last and last_terminates) else values[11 + t + k - 1]
            if t - 2 >= episode[0]:
                errors[t] = sum(0.5**j * rewards[t + j] for j in range(k)) + 0.5**k * value - values[11 + t - 1]
        pairs += [(errors[t], errors[t + 2]) for t in episode if t in errors and t + 2 <= last and actions[t + 2] == 0]
    expected = np.corrcoef(np.array(pairs).T)[0, 1]
    cache = median_cache(buffer, table_target(values), qlearning_prob=1.0, choice="autocorrelation")
    assert len(pairs) >= 3 and cache.lam == pytest.approx(float(np.clip(expected, 0.0, 1.0)))
    assert 0.0 < cache.lam < 1.0


def test_td_errors_that_change_sign_give_lambda_zero():
    # Rewards 1, 2, 0, 3, 1, V(after step i) = 2, 1, 4, 0 (gamma 0.5): delta_1 = 2 + 0.5 - 2 = 0.5, delta_2 = 0 + 2 - 1 = 1,
    # delta_3 = 3 + 0 - 4 = -1, delta_4 = 1 - 0 = 1 (terminated); pairs (0.5, 1), (1, -1), (-1, 1): correlation
    # (-5/3) / sqrt(13/6 * 8/3) = -0.693, clipped to 0: the one-step targets
    target = table_target({11: 2.0, 12: 1.0, 13: 4.0, 14: 0.0})
    cache = median_cache(chain([1.0, 2.0, 0.0, 3.0, 1.0]), target, choice="autocorrelation")
    assert cache.lam == 0.0
    np.testing.assert_allclose(by_slot(cache), [1.0 + 0.5 * 2.0, 2.0 + 0.5 * 1.0, 0.0 + 0.5 * 4.0, 3.0 + 0.0, 1.0])


def test_a_refresh_without_pairs_keeps_delta1():
    cache = median_cache(chain([1.0, 2.0]), table_target({}), choice="autocorrelation", lam=0.8)
    assert cache.lam == 0.8  # one pair at most (none here: the first transition has no predecessor)


def skewed_quantiles(next_observations):
    """Atoms id - 1, id, 1.5 id: their mean, (2.5 id - 1) / 3, is not their median (id) plus a constant."""
    ids = np.asarray(next_observations, dtype=np.float64).reshape(-1)
    return np.stack([ids - 1.0, ids, 1.5 * ids], axis=1).astype(np.float32), ids.astype(np.int64) % 5


def skewed_means(next_observations):
    quantiles, actions = skewed_quantiles(next_observations)
    return quantiles.mean(axis=1), actions


def test_the_refresh_lambda_reads_the_atoms_mean():
    # One long episode through states 11, 12, ... with noisy rewards: TD errors with a trend (the atoms' mean grows
    # along it) and noise, so a correlation strictly between 0 and 1 that the atoms' median would not give
    buffer = chain(list(np.random.default_rng(6).normal(size=30)))
    scalar = median_cache(buffer, skewed_means, qlearning_prob=0.5, choice="autocorrelation")
    chosen = compute_quantile_lambda_returns(
        buffer,
        skewed_quantiles,
        10**9,
        100,
        GAMMA,
        0.9,
        0.5,
        False,
        key=0,
        rng=np.random.default_rng(0),
        choice="autocorrelation",
    )
    assert chosen.lam == pytest.approx(scalar.lam) and 0.0 < chosen.lam < 1.0


@pytest.mark.parametrize("form", ["sampled", "projected"])
def test_the_quantile_critic_takes_the_refresh_lambda_of_its_mean(form):
    buffer = varied_buffer(n_steps=3, seed=5, buffer_size=50, n_adds=80)  # enough windows 3 steps apart to pair
    scalar = median_cache(buffer, fake_values, qlearning_prob=0.5, choice="autocorrelation")
    arguments = (buffer, fake_quantiles, 10**9, 100, GAMMA)
    chosen = compute_quantile_lambda_returns(
        *arguments, 0.9, 0.5, False, key=0, form=form, rng=np.random.default_rng(0), choice="autocorrelation"
    )
    assert chosen.lam == scalar.lam and chosen.lam != 0.9
    fixed = compute_quantile_lambda_returns(*arguments, chosen.lam, 0.5, False, key=0, form=form, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(chosen.returns, fixed.returns)


def varied_buffer(n_steps=1, seed=0, buffer_size=12, n_adds=30):
    """Two envs of different episode lengths, cut and terminated episodes, non-greedy actions, a ring that wraps."""
    rng = np.random.default_rng(seed)
    buffer = make_buffer(buffer_size=buffer_size, n_envs=2, n_steps=n_steps)
    for i in range(n_adds):
        dones = [i % 5 == 4, i % 7 == 6]
        truncated = [i % 10 == 9, False]
        step(buffer, rng.normal(size=2), rng.integers(0, 5, size=2), rng.integers(1, 40, size=2), dones, truncated)
    return buffer


@pytest.mark.parametrize("n_steps", [1, 3])
@pytest.mark.parametrize("qlearning_prob", [0.0, 0.5])
def test_the_median_of_the_fixed_lambda_returns(n_steps, qlearning_prob):
    # DQN(lambda)'s rule written out: the 21 fixed-lambda caches (each checked elsewhere against a literal transcription)
    # and their median per transition, on the whole buffer (one block per env, so every cache has the same transitions)
    buffer = varied_buffer(n_steps)
    fixed = [
        by_slot(compute_lambda_returns(buffer, fake_values, 10**9, 100, GAMMA, lam, qlearning_prob, False, key=0), env)
        for lam in MEDIAN_GRID
        for env in (0, 1)
    ]
    per_lambda = np.array(fixed).reshape(len(MEDIAN_GRID), 2, -1)
    cache = median_cache(buffer, fake_values, qlearning_prob)
    for env in (0, 1):
        np.testing.assert_array_equal(by_slot(cache, env), np.median(per_lambda[:, env], axis=0))


def test_choose_lambda_refuses_an_unknown_rule():
    with pytest.raises(ValueError, match="`lambda_choice`"):
        choose_lambda("mean", lambda lambdas: np.zeros((len(lambdas), 3)), np.ones(3, dtype=bool))


@pytest.mark.parametrize("n_steps", [1, 3])
def test_own_lambdas_draw_the_shared_horizons_when_they_are_equal(n_steps):
    # With one lambda for all, the walk along each trace stops where the shared draw's recurrence stops it
    buffer = varied_buffer(n_steps, seed=1)
    np.random.seed(3)
    layout = lambda_layout(buffer, 10, 4, GAMMA, False)  # blocks of 4: traces cut at blocks' ends too
    next_quantiles, greedy = fake_quantiles(layout.inputs["next_observations"])
    trace = layout.trace(greedy, 0.5)
    shared = quantile_lambda_returns._sampled_targets(layout, next_quantiles, 0.7 * trace, np.random.default_rng(5))
    own = quantile_lambda_returns._sampled_targets_of_own_lambdas(
        layout, next_quantiles, np.full(len(layout.slots), 0.7), trace, np.random.default_rng(5)
    )
    np.testing.assert_allclose(own, shared, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("n_steps", [1, 3])
def test_each_transition_walks_its_own_lambdas_trace(n_steps):
    # Lambdas drawn per transition from the grid: the transitions of each lambda get the targets that the shared draw
    # gives with that lambda for all, on the same uniforms (blocks of 4 cut traces too)
    buffer = varied_buffer(n_steps, seed=4)
    np.random.seed(7)
    layout = lambda_layout(buffer, 10, 4, GAMMA, False)
    next_quantiles, greedy = fake_quantiles(layout.inputs["next_observations"])
    trace = layout.trace(greedy, 0.5)
    lambdas = np.random.default_rng(0).choice(MEDIAN_GRID, size=len(layout.slots))
    own = quantile_lambda_returns._sampled_targets_of_own_lambdas(
        layout, next_quantiles, lambdas, trace, np.random.default_rng(11)
    )
    for lam in np.unique(lambdas):
        shared = quantile_lambda_returns._sampled_targets(layout, next_quantiles, lam * trace, np.random.default_rng(11))
        mine = lambdas == lam
        np.testing.assert_allclose(own[mine], shared[mine], rtol=1e-12, atol=1e-12)


def test_the_quantile_critic_chooses_on_the_mean_and_draws_each_transitions_own_horizon():
    buffer = varied_buffer(n_steps=1, seed=2)
    scalar = median_cache(buffer, fake_values, qlearning_prob=0.5)  # the rule on the atoms' mean
    n_draws = 3000
    targets = []
    for seed in range(n_draws):
        cache = compute_quantile_lambda_returns(
            buffer, fake_quantiles, 10**9, 100, GAMMA, 0.9, 0.5, False, key=0, rng=np.random.default_rng(seed), choice="median"
        )
        assert cache.lam == scalar.lam and cache.lambda_spread == scalar.lambda_spread
        targets.append(np.concatenate([by_slot(cache, 0), by_slot(cache, 1)]).mean(axis=1))
    assert 0.0 < scalar.lambda_spread and scalar.lam != 0.5  # the rule moved away from the middle somewhere
    # The mean of a drawn horizon's target law, over the draws, is the chosen lambda's scalar return (the atoms'
    # offsets have mean 0): within 4 standard errors, and float32's rounding where the horizon is certain
    draws = np.array(targets, dtype=np.float64)
    expected = np.concatenate([by_slot(scalar, 0), by_slot(scalar, 1)])
    error = draws.std(axis=0) / np.sqrt(n_draws)
    assert np.all(np.abs(draws.mean(axis=0) - expected) <= 4 * error + 1e-5 * (1.0 + np.abs(expected)))


def test_the_projected_form_is_refused():
    with pytest.raises(ValueError, match="sampled form"):
        compute_quantile_lambda_returns(
            chain([1.0]), fake_quantiles, 10, 100, GAMMA, 0.9, 0.0, False, key=0, form="projected", choice="median"
        )


@pytest.mark.parametrize(
    ("algo", "choice"),
    [(OffOnDQN, "median"), (OffOnDQN, "autocorrelation"), (OffOnQRDQN, "median"), (OffOnQRDQN, "autocorrelation")],
)
def test_models_log_the_chosen_lambdas_and_keep_the_choice_on_load(algo, choice, tmp_path):
    model = algo("MlpPolicy", "CartPole-v1", lambda_choice=choice, seed=0, **SMALL)
    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    model.learn(400)
    progress = pd.read_csv(tmp_path / "log" / "progress.csv")
    logged = progress["train/lambda"].dropna()
    assert len(logged) and logged.between(0, 1).all()
    # A spread per transition where the rule chooses per transition; one lambda a refresh otherwise
    assert ("train/lambda_std" in progress.columns) == (choice == "median")
    model.save(tmp_path / "model")
    loaded = algo.load(tmp_path / "model", env=model.get_env())
    assert loaded.lambda_choice == choice
    loaded.learn(200)


@pytest.mark.parametrize("algo", [OffOnDQN, OffOnQRDQN])
def test_a_model_saved_before_the_choice_existed_loads_with_a_fixed_lambda(algo, tmp_path):
    model = algo("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    del model.lambda_choice  # as a model saved by a version without the argument
    model.save(tmp_path / "model")
    assert algo.load(tmp_path / "model").lambda_choice == "fixed"


@pytest.mark.parametrize("algo", [OffOnDQN, OffOnQRDQN])
def test_a_fixed_lambda_logs_no_spread(algo, tmp_path):
    model = algo("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    model.learn(400)
    columns = pd.read_csv(tmp_path / "log" / "progress.csv").columns
    assert "train/lambda" in columns and "train/lambda_std" not in columns


@pytest.mark.parametrize(
    ("algo", "kwargs", "message"),
    [
        (OffOnDQN, dict(lambda_choice="mean"), "`lambda_choice` must be one of"),
        (OffOnDQN, dict(lambda_choice="median", mc_mixing="sample"), "needs `mc_mixing='lambda'`"),
        (OffOnQRDQN, dict(lambda_choice="mean"), "`lambda_choice` must be one of"),
        (OffOnQRDQN, dict(lambda_choice="median", lambda_form="projected"), "lambda_form='sampled'"),
        (OffOnQRDQN, dict(lambda_choice="median", lambda_cache=False), "lambda_cache=True"),
        (OffOnQRDQN, dict(lambda_choice="autocorrelation", lambda_cache=False), "lambda_cache=True"),
        (OffOnDQN, dict(lambda_choice="autocorrelation", mc_mixing="max"), "needs `mc_mixing='lambda'`"),
    ],
)
def test_bad_choices_are_refused(algo, kwargs, message):
    with pytest.raises(ValueError, match=message):
        algo("MlpPolicy", "CartPole-v1", **kwargs)
