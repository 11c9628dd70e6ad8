"""
Double Q-learning (``double_q=True``) and dueling networks (``policy_kwargs=dict(dueling=True)``), against values
computed by hand from networks whose weights are set by hand.

The hand-set networks (CartPole-v1's four observations x, x_dot, theta, theta_dot; ``net_arch=[]``, a linear Q):
- online: Q(s) = (x, -x), so its greedy action is 0 where x > 0 and 1 where x < 0;
- target: Q_target(s) = (theta + 0.5, -theta + 0.2).
Where x < 0 and theta > -0.15, the two networks' greedy actions differ: DQN's bootstrap max_a Q_target(s, a) and
double Q-learning's Q_target(s, argmax_a Q(s, a)) are then different numbers.
"""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3 import DQN
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.envs import FakeImageEnv, SimpleMultiObsEnv
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.dqn.policies import DQNPolicy, QNetwork
from test_lambda_nstep import reference_nstep_lambda_returns
from test_lambda_returns import assert_matches_reference, reference_lambda_returns
from torch import nn

from sb3_offon import PAPER_TARGETS, OffOnDQN
from sb3_offon.common.buffers import OffOnReplayBufferSamples, discounted_returns
from sb3_offon.offon_dqn.policies import DuelingHead, DuelingQNetwork

GAMMA = 0.9
# No gradient step and no target update within the tests' runs: the hand-set weights stay as they are
FROZEN = dict(learning_starts=10**6, target_update_interval=10**6, gamma=GAMMA, policy_kwargs=dict(net_arch=[]), device="cpu")
WATKINS = dict(mc_mixing="lambda", mc_initial_prob=0.9, mc_final_prob=0.9, qlearning_initial_prob=1.0, qlearning_final_prob=1)


def set_linear(layer: nn.Linear, weight: list[list[float]], bias: list[float]) -> None:
    with th.no_grad():
        layer.weight.copy_(th.tensor(weight))
        layer.bias.copy_(th.tensor(bias))


def hand_set(model: OffOnDQN) -> OffOnDQN:
    set_linear(model.q_net.q_net[0], [[1, 0, 0, 0], [-1, 0, 0, 0]], [0, 0])
    set_linear(model.q_net_target.q_net[0], [[0, 0, 1, 0], [0, 0, -1, 0]], [0.5, 0.2])
    return model


def hand_bootstrap(next_observations: np.ndarray, double_q: bool) -> tuple[np.ndarray, np.ndarray]:
    """V(s') and the bootstrap action of the hand-set networks, written out with NumPy."""
    obs = np.asarray(next_observations, dtype=np.float64).reshape(-1, 4)
    target_q = np.stack([obs[:, 2] + 0.5, -obs[:, 2] + 0.2], axis=1)
    actions = np.where(obs[:, 0] > 0, 0, 1) if double_q else target_q.argmax(axis=1)
    return target_q[np.arange(len(obs)), actions], actions


def frozen_model(double_q: bool, env="CartPole-v1", **kwargs) -> OffOnDQN:
    return hand_set(OffOnDQN("MlpPolicy", env, seed=0, double_q=double_q, **{**FROZEN, **kwargs}))


# The three next states of the crafted batch: greedy actions agree on the first, differ on the second and third
NEXT_STATES = [[1.0, 0, 0.3, 0], [-1.0, 0, 0.3, 0], [-2.0, 0, -0.1, 0]]


def crafted_batch(discount: float | None = None, next_actions=(0, -1, 1), dones=(0, 0, 1)) -> OffOnReplayBufferSamples:
    n = len(NEXT_STATES)
    return OffOnReplayBufferSamples(
        observations=th.zeros(n, 4),
        actions=th.zeros(n, 1, dtype=th.long),
        next_observations=th.tensor(NEXT_STATES),
        dones=th.tensor(dones, dtype=th.float32).reshape(-1, 1),
        rewards=th.ones(n, 1),
        discounts=None if discount is None else th.full((n, 1), discount),
        next_actions=th.tensor(next_actions).reshape(-1, 1),
        mc_returns=th.full((n, 1), float("nan")),
    )


def coin_flip_targets(model: OffOnDQN, data, use_sarsa=None) -> list[float]:
    with th.no_grad():
        targets, _ = model._targets(data, None, use_sarsa)
    return targets.reshape(-1).tolist()


# --- double Q-learning, coin-flip targets ------------------------------------------------------------------------------


def test_hand_set_networks_disagree_where_intended() -> None:
    values, actions = hand_bootstrap(NEXT_STATES, double_q=False)
    double_values, double_actions = hand_bootstrap(NEXT_STATES, double_q=True)
    np.testing.assert_allclose(values, [0.8, 0.8, 0.4])
    np.testing.assert_allclose(double_values, [0.8, -0.1, 0.3])
    assert actions.tolist() == [0, 0, 0] and double_actions.tolist() == [0, 1, 1]


@pytest.mark.parametrize(
    "double_q, discount, expected",
    [
        # 1 + 0.9 * V(s'); the third sample is terminal
        (False, None, [1 + 0.9 * 0.8, 1 + 0.9 * 0.8, 1.0]),
        (True, None, [1 + 0.9 * 0.8, 1 + 0.9 * -0.1, 1.0]),
        # n-step: the buffer's discount gamma^3 and the n-th next state
        (False, 0.9**3, [1 + 0.729 * 0.8, 1 + 0.729 * 0.8, 1.0]),
        (True, 0.9**3, [1 + 0.729 * 0.8, 1 + 0.729 * -0.1, 1.0]),
    ],
)
def test_qlearning_target(double_q: bool, discount: float | None, expected: list[float]) -> None:
    model = frozen_model(double_q, **PAPER_TARGETS)
    np.testing.assert_allclose(coin_flip_targets(model, crafted_batch(discount)), expected, rtol=1e-6)


@pytest.mark.parametrize("double_q, unknown_next", [(False, 1 + 0.9 * 0.8), (True, 1 + 0.9 * -0.1)])
def test_sampled_sarsa_bootstraps_double_only_where_the_next_action_is_unknown(double_q: bool, unknown_next: float) -> None:
    model = frozen_model(double_q, **PAPER_TARGETS)
    # Sarsa drawn everywhere: the choice keeps it where a' is known (a' = 0 at the first next state, unknown at the second)
    model.mc_prob, model.qlearning_prob = 0.0, 0.0
    data = crafted_batch()
    _, use_sarsa = model._target_choice(data.mc_returns.numpy(), data.next_actions.numpy(), None, np.ones((3, 1), bool))
    assert use_sarsa.reshape(-1).tolist() == [True, False, True]
    targets = coin_flip_targets(model, data, use_sarsa=use_sarsa)
    np.testing.assert_allclose(targets, [1 + 0.9 * 0.8, unknown_next, 1.0], rtol=1e-6)


def test_expected_sarsa_is_unchanged_by_double_q() -> None:
    targets = []
    for double_q in (False, True):
        model = frozen_model(double_q, **{**PAPER_TARGETS, "sarsa_target": "expected"})
        model.exploration_rate = 0.1
        targets.append(coin_flip_targets(model, crafted_batch(), use_sarsa=np.ones((3, 1), dtype=bool)))
    # The epsilon-greedy expectation under the online network: at the second state 0.1 * mean(0.8, -0.1) + 0.9 * -0.1
    np.testing.assert_allclose(targets[0], targets[1])
    np.testing.assert_allclose(targets[1][1], 1 + 0.9 * (0.1 * 0.35 + 0.9 * -0.1), rtol=1e-6)


# --- double Q-learning, truncation bootstrap ---------------------------------------------------------------------------


@pytest.mark.parametrize("double_q", [False, True])
def test_truncated_returns_bootstrap_from_the_double_q_value(double_q: bool) -> None:
    """Episodes cut at 6 steps: the return of their last transition is r + gamma * V(final observation)."""
    env = make_vec_env(lambda: gym.make("CartPole-v1", max_episode_steps=6), n_envs=2, seed=1)
    model = frozen_model(double_q, env=env, exploration_final_eps=1.0, **PAPER_TARGETS)
    np.testing.assert_allclose(model._target_state_values(np.array(NEXT_STATES)), hand_bootstrap(NEXT_STATES, double_q)[0])
    model.learn(60)
    buffer, n = model.replay_buffer, model.replay_buffer.pos
    ends = [(t, e) for t in range(n) for e in range(2) if buffer.dones[t, e] and buffer.timeouts[t, e]]
    assert len(ends) >= 4
    differ = 0
    for t, e in ends:
        value, _ = hand_bootstrap(buffer.next_observations[t, e], double_q)
        np.testing.assert_allclose(buffer.mc_returns[t, e], buffer.rewards[t, e] + GAMMA * value[0], rtol=1e-5)
        differ += hand_bootstrap(buffer.next_observations[t, e], not double_q)[0][0] != value[0]
    assert differ > 0, "some final observations have different DQN and double Q values"
    # ... and the returns before them follow G_t = r_t + gamma * G_{t+1}
    t, e = ends[0]
    tail = hand_bootstrap(buffer.next_observations[t, e], double_q)[0][0]
    expected = discounted_returns(buffer.rewards[: t + 1, e], GAMMA, tail)
    np.testing.assert_allclose(buffer.mc_returns[: t + 1, e], expected, rtol=1e-5)


# --- double Q-learning, lambda-returns ---------------------------------------------------------------------------------


@pytest.mark.parametrize("n_steps", [1, 3])
@pytest.mark.parametrize("double_q", [False, True])
def test_lambda_returns_bootstrap_and_cut_traces_with_the_online_argmax(double_q: bool, n_steps: int) -> None:
    """Watkins's Q(lambda): V(s) and the greedy action of the trace-cut test are double Q-learning's with double_q."""
    env = make_vec_env("CartPole-v1", n_envs=2, seed=2)
    model = frozen_model(double_q, env=env, buffer_size=300, n_steps=n_steps, exploration_final_eps=0.5, **WATKINS)
    model.learn(400)  # the ring wraps; episodes of different lengths per env
    model._lambda_cache = None
    cache = model._refreshed_lambda_cache(10**6)  # the whole buffer, one block per env

    def target(next_observations):
        return hand_bootstrap(next_observations, double_q)

    if n_steps == 1:
        reference = reference_lambda_returns(model.replay_buffer, target, GAMMA, 0.9, 1.0)
        other = reference_lambda_returns(model.replay_buffer, lambda obs: hand_bootstrap(obs, not double_q), GAMMA, 0.9, 1.0)
    else:
        reference = reference_nstep_lambda_returns(model.replay_buffer, target, 0.9, 1.0, gamma=GAMMA)
        other = reference_nstep_lambda_returns(
            model.replay_buffer, lambda obs: hand_bootstrap(obs, not double_q), 0.9, 1.0, gamma=GAMMA
        )
    assert_matches_reference(cache, reference)
    assert any(not np.isclose(reference[key], other[key]) for key in reference), "the two readings differ on this data"


# --- dueling networks --------------------------------------------------------------------------------------------------


class NoisyExtractor(FlattenExtractor):
    """A flatten extractor followed by BatchNorm and Dropout: layers whose training mode changes their output."""

    def __init__(self, observation_space: gym.Space) -> None:
        super().__init__(observation_space)
        self.noise = nn.Sequential(nn.BatchNorm1d(self.features_dim), nn.Dropout(0.5))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.noise(super().forward(observations))


@pytest.mark.parametrize("sarsa_target", ["sampled", "expected"])
def test_the_online_argmax_at_next_states_is_taken_in_evaluation_mode(sarsa_target: str) -> None:
    # As train() runs it: the networks in training mode. The online network's choice at s' must not draw Dropout masks
    # (the same states, the same actions) nor move BatchNorm's running statistics with next states
    kwargs = {"policy_kwargs": {"features_extractor_class": NoisyExtractor, "net_arch": [16]}, "sarsa_target": sarsa_target}
    model = OffOnDQN("MlpPolicy", "CartPole-v1", double_q=True, seed=0, **PAPER_TARGETS, **kwargs)
    model.policy.set_training_mode(True)
    batch_norm = model.q_net.features_extractor.noise[0]
    statistics = batch_norm.running_mean.clone()
    observations = th.randn(256, 4) * 3 + 1
    with th.no_grad():
        first, second = model._bootstrap(observations)[1], model._bootstrap(observations)[1]
    assert th.equal(first, second)
    assert th.equal(batch_norm.running_mean, statistics)
    assert model.q_net.training, "training mode is given back"


def test_dueling_output_is_value_plus_advantage_minus_its_mean() -> None:
    model = OffOnDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(dueling=True, net_arch=[]), device="cpu")
    head = model.q_net.q_net
    assert isinstance(model.q_net, DuelingQNetwork) and isinstance(head, DuelingHead)
    set_linear(head.value_stream[0], [[1, 0, 0, 0]], [0.5])
    set_linear(head.advantage_stream[0], [[0, 1, 0, 0], [0, 0, 0, 1]], [0, 0])
    # s = (1, 2, 3, 4): V = 1.5, A = (2, 4), mean A = 3, so Q = (0.5, 2.5)
    obs = np.array([[1.0, 2.0, 3.0, 4.0]], dtype=np.float32)
    with th.no_grad():
        q_values = model.q_net(th.as_tensor(obs))
    np.testing.assert_allclose(q_values.numpy(), [[0.5, 2.5]])
    assert model.predict(obs, deterministic=True)[0].tolist() == [1]
    model.q_net_target.load_state_dict(model.q_net.state_dict())
    with th.no_grad():
        np.testing.assert_allclose(model.q_net_target(th.as_tensor(obs)).numpy(), [[0.5, 2.5]])


def test_dueling_streams_follow_net_arch() -> None:
    model = OffOnDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(dueling=True, net_arch=[32, 16]), device="cpu")
    for network in (model.q_net, model.q_net_target):
        head = network.q_net
        assert [layer.out_features for layer in head.value_stream if isinstance(layer, nn.Linear)] == [32, 16, 1]
        assert [layer.out_features for layer in head.advantage_stream if isinstance(layer, nn.Linear)] == [32, 16, 2]
    # Separate networks: the target's parameters are copies, not the same tensors
    assert model.q_net.features_extractor is not model.q_net_target.features_extractor
    assert all(a is not b for a, b in zip(model.q_net.parameters(), model.q_net_target.parameters(), strict=True))


def test_without_dueling_the_policy_builds_sb3s_network() -> None:
    ours = OffOnDQN("MlpPolicy", "CartPole-v1", seed=3, device="cpu")
    theirs = DQN("MlpPolicy", "CartPole-v1", seed=3, device="cpu")
    assert type(ours.q_net) is QNetwork and type(ours.q_net.q_net) is nn.Sequential and ours.policy.dueling is False
    assert [type(module) for module in ours.q_net.modules()] == [type(module) for module in theirs.q_net.modules()]
    for (name, ours_param), (_, their_param) in zip(
        ours.policy.state_dict().items(), theirs.policy.state_dict().items(), strict=True
    ):
        assert th.equal(ours_param, their_param), name


def test_dueling_model_saves_and_loads(tmp_path: Path) -> None:
    model = OffOnDQN(
        "MlpPolicy",
        "CartPole-v1",
        policy_kwargs=dict(dueling=True, net_arch=[16]),
        double_q=True,
        learning_starts=50,
        seed=0,
        device="cpu",
    )
    model.learn(200)
    obs = np.random.default_rng(0).normal(size=(8, 4)).astype(np.float32)
    actions = model.predict(obs, deterministic=True)[0]
    model.save(tmp_path / "model")
    loaded = OffOnDQN.load(tmp_path / "model", device="cpu")
    assert loaded.double_q is True and loaded.policy.dueling is True
    assert isinstance(loaded.q_net.q_net, DuelingHead) and isinstance(loaded.q_net_target.q_net, DuelingHead)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], actions)
    for (name, param), (_, loaded_param) in zip(
        model.policy.state_dict().items(), loaded.policy.state_dict().items(), strict=True
    ):
        assert th.equal(param, loaded_param), name


def test_a_dueling_model_loads_into_sb3s_dqn_and_sb3s_into_offon_dqn(tmp_path: Path) -> None:
    # OffOnDQN's policy class is saved with the model: SB3's DQN loads it and acts and trains the same network
    model = OffOnDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(dueling=True, net_arch=[16]), learning_starts=50, seed=0)
    model.learn(200)
    model.save(tmp_path / "dueling")
    observations = np.random.default_rng(0).normal(size=(8, 4)).astype(np.float32)
    sb3 = DQN.load(tmp_path / "dueling", env=model.get_env())
    assert isinstance(sb3.q_net.q_net, DuelingHead)
    np.testing.assert_array_equal(sb3.predict(observations, deterministic=True)[0], model.predict(observations, True)[0])
    sb3.learn(100)
    # And SB3's DQN file loads as OffOnDQN, which trains it
    plain = DQN("MlpPolicy", "CartPole-v1", learning_starts=50, seed=0)
    plain.learn(100)
    plain.save(tmp_path / "plain")
    loaded = OffOnDQN.load(tmp_path / "plain", env=plain.get_env())
    np.testing.assert_array_equal(loaded.predict(observations, True)[0], plain.predict(observations, True)[0])
    updates = loaded._n_updates
    loaded.learn(100)
    assert loaded._n_updates > updates


def test_soft_target_updates_move_every_dueling_parameter() -> None:
    kwargs = dict(policy_kwargs=dict(dueling=True, net_arch=[8]), tau=0.5, target_update_interval=1, learning_starts=10)
    model = OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, **kwargs)
    before = {name: value.clone() for name, value in model.q_net_target.state_dict().items()}
    model.learn(30)
    after = model.q_net_target.state_dict()
    assert before.keys() == after.keys() and any("value" in name for name in before)
    for name, value in before.items():
        assert not th.equal(value, after[name]), name
        # Polyak averaging: each target parameter moved towards the online one
        online = model.q_net.state_dict()[name]
        assert (after[name] - online).abs().sum() < (value - online).abs().sum() + 1e-6, name


@pytest.mark.parametrize(
    "policy, make_env",
    [
        ("CnnPolicy", lambda: FakeImageEnv(screen_height=40, screen_width=40, n_channels=1, discrete=True)),
        ("MultiInputPolicy", lambda: SimpleMultiObsEnv(random_start=True)),
    ],
    ids=["cnn", "multi-input"],
)
@pytest.mark.parametrize("mc_mixing", ["lambda", "sample"])
def test_dueling_and_double_q_train_with_every_policy(policy: str, make_env, mc_mixing: str) -> None:
    env = make_vec_env(make_env, n_envs=2, seed=0)
    model = OffOnDQN(
        policy,
        env,
        policy_kwargs=dict(dueling=True),
        double_q=True,
        mc_mixing=mc_mixing,
        buffer_size=300,
        learning_starts=50,
        batch_size=8,
        target_update_interval=40,
        seed=0,
        device="cpu",
    )
    before = [param.clone() for param in model.q_net.parameters()]
    model.learn(200)
    assert isinstance(model.q_net.q_net, DuelingHead) and model._n_updates > 0
    assert any(not th.equal(a, b) for a, b in zip(before, model.q_net.parameters(), strict=True))
    assert model.predict(env.reset(), deterministic=True)[0].shape == (2,)


def test_dueling_with_the_minatar_network() -> None:
    pytest.importorskip("minatar", reason="the 'minatar' extra is not installed")
    from sb3_offon import MinAtarCNN

    model = OffOnDQN(
        "CnnPolicy",
        "MinAtar/Breakout-v1",
        policy_kwargs=dict(features_extractor_class=MinAtarCNN, net_arch=[], dueling=True),
        learning_starts=50,
        buffer_size=200,
        seed=0,
        device="cpu",
    )
    model.learn(120)
    assert isinstance(model.q_net.features_extractor, MinAtarCNN) and isinstance(model.q_net.q_net, DuelingHead)
    assert [layer.out_features for layer in model.q_net.q_net.advantage_stream] == [3]


@pytest.mark.parametrize("name, value", [("double_q", 1), ("double_q", "yes")])
def test_bad_double_q_names_the_parameter(name: str, value) -> None:
    with pytest.raises(ValueError, match=f"`{name}` must be True or False"):
        OffOnDQN("MlpPolicy", "CartPole-v1", device="cpu", **{name: value})


def test_bad_dueling_names_the_parameter() -> None:
    with pytest.raises(ValueError, match="`dueling` must be True or False"):
        OffOnDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(dueling="yes"), device="cpu")
    # NumPy's bools are bools, as for double_q
    model = OffOnDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(dueling=np.bool_(True)), double_q=np.bool_(True))
    assert model.policy.dueling is True and isinstance(model.q_net.q_net, DuelingHead)


# --- the policy's mode switch and parameter list (what SB3 calls at every env step) --------------------------------------


class CountingExtractor(FlattenExtractor):
    """A features extractor that overrides ``train``: the policy must then switch modes SB3's way, through it."""

    calls = 0

    def train(self, mode: bool = True):
        CountingExtractor.calls += 1
        return super().train(mode)


@pytest.mark.parametrize("dueling", [False, True])
def test_training_mode_flags_are_sb3s(dueling: bool) -> None:
    model = OffOnDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(dueling=dueling, net_arch=[8]), device="cpu")
    reference = OffOnDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(dueling=dueling, net_arch=[8]), device="cpu")
    for mode in (True, False, True):
        model.policy.set_training_mode(mode)
        DQNPolicy.set_training_mode(reference.policy, mode)  # SB3's own way, through Module.train
        flags = [module.training for module in model.policy.modules()]
        assert flags == [module.training for module in reference.policy.modules()]
        assert all(module.training == mode for module in model.q_net.modules()) and model.policy.training == mode
        assert not any(module.training for module in model.q_net_target.modules())


def test_a_module_that_overrides_train_is_switched_through_it() -> None:
    model = OffOnDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(features_extractor_class=CountingExtractor), device="cpu")
    before = CountingExtractor.calls
    model.policy.set_training_mode(True)
    assert CountingExtractor.calls == before + 1 and model.q_net.features_extractor.training


def test_parameter_list_is_the_policys_and_follows_a_reload(tmp_path: Path) -> None:
    model = OffOnDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(net_arch=[8]), device="cpu")
    assert model._parameter_list() == list(model.policy.parameters())
    assert model._parameter_list() is model._parameter_list()  # listed once
    model.save(tmp_path / "model")
    loaded = OffOnDQN.load(tmp_path / "model", device="cpu")
    assert loaded._parameter_list() == list(loaded.policy.parameters())
    assert all(a is not b for a, b in zip(loaded._parameter_list(), model._parameter_list(), strict=True))
