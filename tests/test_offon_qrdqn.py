"""OffOnQRDQN: QR-DQN's own targets at lambda = 0, a drop-in for QR-DQN (arguments, policies, envs, save/load), and
no host read-back per gradient step."""

import inspect

import numpy as np
import pytest
import sb3_contrib
import torch as th
from sb3_contrib.qrdqn import qrdqn as sb3_contrib_qrdqn
from stable_baselines3.common.buffers import NStepReplayBuffer, ReplayBuffer
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.envs import FakeImageEnv, SimpleMultiObsEnv
from stable_baselines3.common.logger import KVWriter, Logger
from test_train_loop import count_read_backs  # noqa: F401  (a fixture)

from sb3_offon import OffOnDQN, OffOnNStepReplayBuffer, OffOnQRDQN, OffOnReplayBuffer
from sb3_offon.qrdqn import QRDQN

SMALL = dict(
    learning_starts=50,
    batch_size=16,
    train_freq=4,
    target_update_interval=40,
    buffer_size=2000,
    policy_kwargs=dict(net_arch=[16], n_quantiles=7),
)
ZERO_LAMBDA = dict(mc_initial_prob=0.0, mc_final_prob=0.0)


def contrib_target_quantiles(model, batch_inds: np.ndarray, monkeypatch) -> th.Tensor:
    """The target quantiles that sb3-contrib's ``QRDQN.train`` builds for the stored transitions ``batch_inds`` (env 0)."""
    captured = {}

    def capture(current_quantiles, target_quantiles, *args, **kwargs):
        captured["target"] = target_quantiles.detach().clone()
        return (current_quantiles * 0.0).sum()

    buffer = model.replay_buffer
    sb3_samples = NStepReplayBuffer._get_samples if isinstance(buffer, NStepReplayBuffer) else ReplayBuffer._get_samples
    with monkeypatch.context() as patch:
        patch.setattr(sb3_contrib_qrdqn, "quantile_huber_loss", capture)
        patch.setattr(buffer, "sample", lambda batch_size, env=None: sb3_samples(buffer, batch_inds, env=env))
        sb3_contrib.QRDQN.train(model, gradient_steps=1, batch_size=len(batch_inds))
    return captured["target"]


@pytest.mark.parametrize("n_steps", [1, 3])
@pytest.mark.parametrize("form", ["sampled", "projected"])
def test_lambda_zero_targets_are_sb3_contribs_qrdqn_targets(monkeypatch, n_steps, form):
    model = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=0, n_steps=n_steps, lambda_form=form, **ZERO_LAMBDA, **SMALL)
    model.learn(300)  # a few episodes, terminated ones and a running one
    model.mc_prob = 0.0
    cache = model._compute_lambda_cache(10**9, key=0)
    order = np.argsort(cache.slots)
    slots, ours = cache.slots[order], cache.returns[order]
    theirs = contrib_target_quantiles(model, slots, monkeypatch).numpy()
    if form == "projected":  # a projection sorts the atoms (the loss does not depend on their order)
        ours, theirs = np.sort(ours, axis=1), np.sort(theirs, axis=1)
    np.testing.assert_allclose(ours, theirs, rtol=1e-5, atol=1e-5)
    assert len(slots) == model.replay_buffer.pos  # every stored transition


def test_the_arguments_are_qrdqns_plus_offon_dqns_lambda_ones():
    ours = inspect.signature(OffOnQRDQN.__init__).parameters
    for name, parameter in inspect.signature(sb3_contrib.QRDQN.__init__).parameters.items():
        assert name in ours, name
        assert ours[name].default == parameter.default, name
    offon = inspect.signature(OffOnDQN.__init__).parameters
    for name in ("mc_initial_prob", "mc_final_prob", "mc_fraction", "qlearning_initial_prob", "qlearning_final_prob",
                 "qlearning_fraction", "mc_mixing", "sarsa_target", "mc_truncation", "loss", "lambda_block_size",
                 "lambda_refresh_interval", "double_q", "n_steps"):  # fmt: skip
        assert ours[name].default == offon[name].default, name
    assert issubclass(OffOnQRDQN, QRDQN) and issubclass(OffOnQRDQN, sb3_contrib.QRDQN)
    # every argument documented
    for name in ours:
        if name != "self":
            assert f":param {name}:" in OffOnQRDQN.__doc__, name


def test_moving_from_offon_dqn_changes_one_word():
    kwargs = dict(mc_initial_prob=0.8, mc_final_prob=0.8, qlearning_initial_prob=1.0, qlearning_final_prob=1.0,
                  mc_mixing="lambda", mc_truncation="terminal", loss="huber", lambda_block_size=50, double_q=True,
                  n_steps=2, seed=1, **SMALL)  # fmt: skip
    kwargs["policy_kwargs"] = dict(net_arch=[16])  # (n_quantiles is QR-DQN's only)
    OffOnDQN("MlpPolicy", "CartPole-v1", **kwargs).learn(120)
    model = OffOnQRDQN("MlpPolicy", "CartPole-v1", **kwargs).learn(120)
    assert isinstance(model.replay_buffer, OffOnNStepReplayBuffer)


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("mc_mixing", "sample", "coin-flip"),
        ("mc_mixing", "max", "coin-flip"),
        ("loss", "mse", "quantile Huber"),
        ("lambda_form", "exact", "lambda_form"),
        ("mc_initial_prob", 1.5, "mc_initial_prob"),
        ("mc_truncation", "cut", "mc_truncation"),
        ("double_q", 1, "double_q"),
        ("lambda_block_size", 0, "lambda_block_size"),
    ],
)
def test_bad_input_names_the_parameter(name, value, message):
    with pytest.raises(ValueError, match=message):
        OffOnQRDQN("MlpPolicy", "CartPole-v1", **{name: value})


@pytest.mark.parametrize("dueling", [True, False])
def test_a_dueling_network_is_refused_by_name(dueling):
    with pytest.raises(ValueError, match=r"policy_kwargs\['dueling'\]"):
        OffOnQRDQN("MlpPolicy", "CartPole-v1", policy_kwargs=dict(dueling=dueling))


def test_a_plain_buffer_is_refused():
    with pytest.raises(ValueError, match="replay_buffer_class"):
        OffOnQRDQN("MlpPolicy", "CartPole-v1", replay_buffer_class=ReplayBuffer)


class RecordingWriter(KVWriter):
    def __init__(self):
        self.keys = set()

    def write(self, key_values, key_excluded, step=0):
        self.keys |= set(key_values)


def test_learns_on_several_envs_logs_and_saves(tmp_path):
    env = make_vec_env("CartPole-v1", n_envs=2, seed=0)
    model = OffOnQRDQN("MlpPolicy", env, seed=0, **SMALL)
    writer = RecordingWriter()
    model.set_logger(Logger(None, [writer]))
    eval_callback = EvalCallback(make_vec_env("CartPole-v1", n_envs=1, seed=1), eval_freq=100, n_eval_episodes=2)
    model.learn(400, callback=eval_callback)
    assert {"train/loss", "train/lambda", "train/trace_cut_fraction", "train/mc_prob", "train/n_updates"} <= writer.keys
    assert model.replay_buffer.n_envs == 2 and isinstance(model.replay_buffer, OffOnReplayBuffer)
    assert eval_callback.n_calls == 200 and np.isfinite(eval_callback.last_mean_reward)  # 400 steps on two envs

    model.save(tmp_path / "model")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = OffOnQRDQN.load(tmp_path / "model", env=env)
    for (name, ours), (_, theirs) in zip(model.policy.state_dict().items(), loaded.policy.state_dict().items(), strict=True):
        assert th.equal(ours, theirs), name
    assert (loaded.mc_initial_prob, loaded.lambda_form, loaded.policy.n_quantiles) == (0.9, "sampled", 7)
    assert loaded.target_rng.bit_generator.state == model.target_rng.bit_generator.state
    loaded.load_replay_buffer(tmp_path / "buffer")
    assert loaded.replay_buffer.pos == model.replay_buffer.pos
    loaded.learn(200, reset_num_timesteps=False)
    # a model saved by OffOnQRDQN does not load as another algorithm's lambda arguments silently: its class is its own
    assert type(loaded) is OffOnQRDQN


@pytest.mark.parametrize(
    "policy, make_env",
    [
        ("CnnPolicy", lambda: FakeImageEnv(screen_height=40, screen_width=40, n_channels=1, discrete=True)),
        ("MultiInputPolicy", lambda: SimpleMultiObsEnv(random_start=True)),
    ],
)
def test_qrdqns_policies(policy, make_env):
    model = OffOnQRDQN(policy, make_env(), seed=0, **{**SMALL, "policy_kwargs": dict(n_quantiles=5)})
    model.learn(120)
    assert model._lambda_cache is not None and model._lambda_cache.returns.shape[1] == 5


def test_minatar_network():
    pytest.importorskip("minatar")
    from sb3_offon import MinAtarCNN

    model = OffOnQRDQN(
        "CnnPolicy",
        "MinAtar/Breakout-v0",
        seed=0,
        **{**SMALL, "policy_kwargs": dict(features_extractor_class=MinAtarCNN, net_arch=[], n_quantiles=5)},
    )
    model.learn(120)
    assert isinstance(model.policy.quantile_net.features_extractor, MinAtarCNN)


def test_double_q_bootstraps_at_the_online_networks_argmax():
    model = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=0, double_q=True, **SMALL)
    model.learn(100)
    th.manual_seed(0)
    with th.no_grad():
        for parameter in model.quantile_net_target.parameters():
            parameter.add_(th.randn_like(parameter))  # so that the two networks' argmaxes differ
    observations = th.randn(64, 4)
    with th.no_grad():
        quantiles, actions = model._bootstrap_quantiles(observations)
        online = model.quantile_net(observations).mean(dim=1).argmax(dim=1)
        target = model.quantile_net_target(observations)
    assert th.equal(actions, online)
    assert not th.equal(online, target.mean(dim=1).argmax(dim=1))
    assert th.equal(quantiles, target[th.arange(64), :, online])


def test_the_default_form_is_sampled_and_the_projected_one_trains():
    assert OffOnQRDQN("MlpPolicy", "CartPole-v1").lambda_form == "sampled"
    model = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=0, lambda_form="projected", **SMALL)
    model.learn(200)
    assert model._lambda_cache.returns.shape[1] == 7 and np.isfinite(model._lambda_cache.returns).all()


@pytest.mark.parametrize("options", [{}, {"double_q": True}, {"lambda_form": "projected"}, {"n_steps": 3}])
def test_read_backs_do_not_grow_with_gradient_steps(count_read_backs, options):  # noqa: F811
    def read_backs(gradient_steps):
        model = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=0, gradient_steps=gradient_steps, **{**SMALL, **options})
        model.learn(200)
        model._lambda_cache = None  # the call refreshes the lambda-returns too: their read-back is counted
        before = count_read_backs["n"]
        model.train(gradient_steps, batch_size=16)
        return count_read_backs["n"] - before

    # the refresh's one read of the quantiles and actions (.cpu, .numpy) and the call's loss (.item)
    assert read_backs(4) == read_backs(32) == 3


def test_same_seed_same_result():
    def parameters():
        model = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=3, **SMALL)
        model.learn(300)
        return [p.clone() for p in model.policy.parameters()]

    for ours, theirs in zip(parameters(), parameters(), strict=True):
        assert th.equal(ours, theirs)


@pytest.mark.parametrize("max_grad_norm", [None, 0.5])
def test_gradients_are_clipped_only_with_max_grad_norm(monkeypatch, max_grad_norm):
    # QR-DQN's default clips nothing; with max_grad_norm, every gradient step clips all of the policy's parameters
    model = OffOnQRDQN("MlpPolicy", "CartPole-v1", seed=0, max_grad_norm=max_grad_norm, **SMALL)
    model.learn(100)
    calls = []
    clip = th.nn.utils.clip_grad_norm_

    def counting_clip(parameters, norm):
        calls.append((list(parameters), norm))
        return clip(parameters, norm)

    monkeypatch.setattr(th.nn.utils, "clip_grad_norm_", counting_clip)
    model.train(gradient_steps=5, batch_size=16)
    if max_grad_norm is None:
        assert calls == []
    else:
        assert len(calls) == 5
        assert all(norm == 0.5 and len(params) == len(list(model.policy.parameters())) for params, norm in calls)
