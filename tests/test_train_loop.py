"""OffOnDQN's training loop: the same updates as a plain per-step loop, and no device read-backs per gradient step."""

import sys

import numpy as np
import pytest
import torch as th
from helpers import assert_same_parameters
from stable_baselines3 import DQN
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.envs import SimpleMultiObsEnv

import sb3_offon.offon_dqn.offon_dqn as offon_dqn_module
from sb3_offon import PAPER_TARGETS, OffOnDQN
from sb3_offon.common import chunks

SMALL = dict(
    learning_starts=100,
    batch_size=16,
    train_freq=50,
    target_update_interval=100,
    policy_kwargs=dict(net_arch=[16]),
    device="cpu",
)
# The paper's coin flips (OffOnDQN's defaults are lambda-returns), both schedules in the middle all along, so that every
# kind of target is drawn
MIXED = dict(mc_mixing="sample", mc_initial_prob=0.5, mc_final_prob=0.5, qlearning_initial_prob=0.5, qlearning_final_prob=0.5)


class PerStepOffOnDQN(OffOnDQN):
    """The loop that OffOnDQN's replaced, written as SB3's DQN writes it: sample, targets, update, one step at a time."""

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self.mc_prob = self.mc_schedule(self._current_progress_remaining)
        self.qlearning_prob = self.qlearning_schedule(self._current_progress_remaining)
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        uniforms = self.target_rng.random((2, gradient_steps, batch_size, 1), dtype=np.float32)
        for step in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            use_mc, use_sarsa = self._target_choice(
                data.mc_returns.numpy(),
                data.next_actions.numpy(),
                uniforms[0, step] < self.mc_prob,
                uniforms[1, step] >= self.qlearning_prob,
            )
            with th.no_grad():
                targets, _ = self._targets(data, use_mc, use_sarsa)
            current_q_values = th.gather(self.q_net(data.observations), dim=1, index=data.actions.long())
            loss = offon_dqn_module.LOSS_FUNCTIONS[self.loss](current_q_values, targets)
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
        self._n_updates += gradient_steps


OPTIONS = {
    "sample": {},
    "sample-expected-sarsa": {"sarsa_target": "expected"},
    "convex": {"mc_mixing": "convex"},
    "max": {"mc_mixing": "max"},
    "max-expected-sarsa": {"mc_mixing": "max", "sarsa_target": "expected"},
    "terminal-mse": {"mc_truncation": "terminal", "loss": "mse"},
    "3-step": {"n_steps": 3},
    "optimize-memory": {"optimize_memory_usage": True, "replay_buffer_kwargs": {"handle_timeout_termination": False}},
}


@pytest.mark.parametrize("n_envs", [1, 3])
@pytest.mark.parametrize("options", OPTIONS.values(), ids=OPTIONS.keys())
def test_trains_to_the_parameters_of_the_per_step_loop(options, n_envs):
    # A buffer smaller than the run, so that sampling also covers a full, wrapped-around buffer
    def train(algo):
        env = make_vec_env("CartPole-v1", n_envs=n_envs, seed=3)
        model = algo("MlpPolicy", env, seed=3, buffer_size=300, gradient_steps=12, **{**SMALL, **MIXED, **options})
        return model.learn(900)

    ours, reference = train(OffOnDQN), train(PerStepOffOnDQN)
    assert ours.replay_buffer.full and ours._n_updates == reference._n_updates > 0
    assert_same_parameters(ours, reference)
    # The loops leave the global RNG and the draws' generator in the same state
    assert ours.target_rng.bit_generator.state == reference.target_rng.bit_generator.state


def test_chunked_gathering_trains_to_the_same_parameters(monkeypatch):
    # Chunks of 3 minibatches of 16 CartPole observations (128 bytes as float32 observations and next observations)
    monkeypatch.setattr(chunks, "MAX_CHUNK_BYTES", 3 * 16 * 32 + 5)

    def train(algo):
        model = algo("MlpPolicy", "CartPole-v1", seed=4, buffer_size=500, gradient_steps=10, **SMALL, **MIXED)
        return model.learn(600)

    ours = train(OffOnDQN)
    assert ours._steps_per_chunk(16) == 3
    assert_same_parameters(ours, train(PerStepOffOnDQN))


def test_dict_observations_train_to_the_parameters_of_the_per_step_loop():
    def train(algo):
        np.random.seed(2)  # SimpleMultiObsEnv draws its observation table from the global RNG when it is made
        env = make_vec_env(lambda: SimpleMultiObsEnv(random_start=True), n_envs=2, seed=2)
        model = algo("MultiInputPolicy", env, seed=2, buffer_size=400, gradient_steps=6, **SMALL, **MIXED)
        return model.learn(500)

    assert_same_parameters(train(OffOnDQN), train(PerStepOffOnDQN))


def test_sample_minibatches_is_sampling_step_by_step():
    model = OffOnDQN(
        "MlpPolicy", make_vec_env("CartPole-v1", n_envs=2, seed=0), seed=0, buffer_size=300, **SMALL, **PAPER_TARGETS
    )
    model.learn(500)
    buffer = model.replay_buffer
    np.random.seed(7)
    minibatches = buffer.sample_minibatches(5, 16)
    state_after = np.random.get_state(legacy=False)
    np.random.seed(7)
    one_by_one = [buffer.sample(16) for _ in range(5)]
    assert str(np.random.get_state(legacy=False)) == str(state_after)
    for name, column in minibatches.samples._asdict().items():
        expected = [getattr(samples, name) for samples in one_by_one]
        if column is None:
            assert all(value is None for value in expected), name
        else:
            assert th.equal(column.nan_to_num(-7.0), th.cat(expected).nan_to_num(-7.0)), name  # NaN: unknown return
    # The host copies are the columns the tensors hold
    np.testing.assert_array_equal(minibatches.mc_returns, minibatches.samples.mc_returns.numpy())
    np.testing.assert_array_equal(minibatches.next_actions, minibatches.samples.next_actions.numpy())


# --- read-backs from the device -----------------------------------------------------------------------------------

READ_BACKS = ("item", "numpy", "cpu", "tolist", "__bool__", "__float__", "__int__", "__index__")


@pytest.fixture
def count_read_backs(monkeypatch):
    """
    Count the calls that would copy a tensor from the device to the host, made from this project's or SB3's code.

    On a CPU-only machine nothing is read back from a GPU; these are the calls that would be, so counting them here
    tells what the loop would do on one. Calls from within torch (Adam reads its step counters, which live on the
    host) are left out: they are the same for any training loop.
    """
    counts = {"n": 0}

    def wrap(original):
        def counted(self, *args, **kwargs):
            caller = sys._getframe(1).f_globals.get("__name__", "")
            if caller.startswith(("sb3_offon", "stable_baselines3")):
                counts["n"] += 1
            return original(self, *args, **kwargs)

        return counted

    for name in READ_BACKS:
        monkeypatch.setattr(th.Tensor, name, wrap(getattr(th.Tensor, name)))
    return counts


def read_backs_of_one_train_call(algo, gradient_steps: int, counts: dict, **kwargs) -> int:
    model = algo("MlpPolicy", "CartPole-v1", seed=0, buffer_size=1000, gradient_steps=gradient_steps, **SMALL, **kwargs)
    model.learn(200)  # fills the buffer past learning_starts
    if getattr(model, "mc_mixing", None) == "lambda":  # SB3's DQN has no such attribute
        model._lambda_cache = None  # the call refreshes the lambda-returns too: their read-backs are counted
    before = counts["n"]
    model.train(gradient_steps, batch_size=16)
    return counts["n"] - before


@pytest.mark.parametrize(
    "options",
    [
        MIXED,
        {**MIXED, "mc_mixing": "max"},
        {**MIXED, "sarsa_target": "expected"},
        {**PAPER_TARGETS, "n_steps": 3},
        {},
        {**MIXED, "double_q": True},
        {"double_q": True},
    ],
    ids=["sample", "max", "expected-sarsa", "paper-3-step", "lambda-defaults", "sample-double-q", "lambda-double-q"],
)
def test_read_backs_do_not_grow_with_gradient_steps(count_read_backs, options):
    few = read_backs_of_one_train_call(OffOnDQN, 4, count_read_backs, **options)
    many = read_backs_of_one_train_call(OffOnDQN, 32, count_read_backs, **options)
    # lambda: the call's loss, and the refresh of the lambda-returns' one read of V and the greedy actions (.cpu, .numpy)
    if "mc_mixing" not in options:
        assert few == many == 3
    else:
        assert few == many <= 2


def test_the_read_back_counter_sees_sb3_dqn_reading_the_loss_at_each_step(count_read_backs):
    # The counter works: SB3's DQN reads its loss back once per gradient step
    few = read_backs_of_one_train_call(DQN, 4, count_read_backs)
    many = read_backs_of_one_train_call(DQN, 32, count_read_backs)
    assert many - few == 28
