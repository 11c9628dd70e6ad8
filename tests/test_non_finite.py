"""
No silent NaN (sb3_offon/common/non_finite.py): a non-finite reward stops training at the step it is returned, naming the
env and the step, with nothing of that step stored; ``non_finite="skip"`` skips the step and cuts the running episodes
as truncations; a non-finite loss stops training at the training call that logs it.
"""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3 import DQN
from stable_baselines3.common.env_util import make_vec_env

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.common.non_finite import NonFiniteCheck, NonFiniteError, non_finite_rewards
from sb3_offon.common.prioritized_buffers import PrioritizedOffOnReplayBuffer
from sb3_offon.qrdqn import QRDQN

SMALL = dict(learning_starts=50, buffer_size=1_000, batch_size=16, train_freq=4, target_update_interval=100, seed=0)


class BadRewardAt(gym.Wrapper):
    """Returns ``value`` instead of the reward at the env's ``step``-th step (counted from 1 over its whole life)."""

    def __init__(self, env: gym.Env, step: int, value: float) -> None:
        super().__init__(env)
        self.bad_step, self.value, self.n_steps = step, value, 0

    def step(self, action):  # type: ignore[no-untyped-def]
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.n_steps += 1
        return observation, (self.value if self.n_steps == self.bad_step else reward), terminated, truncated, info


class Corridor(gym.Env):
    """Reward 1 at every step, episodes of ``length`` steps ending in a terminal state; the observation is the step."""

    observation_space = gym.spaces.Box(0.0, 100.0, (1,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, length: int = 10) -> None:
        self.length, self.t = length, 0

    def reset(self, *, seed=None, options=None):  # type: ignore[no-untyped-def]
        super().reset(seed=seed)
        self.t = 0
        return np.array([0.0], np.float32), {}

    def step(self, action):  # type: ignore[no-untyped-def]
        self.t += 1
        return np.array([self.t], np.float32), 1.0, self.t >= self.length, False, {}


def cartpole(step: int = 300, value: float = float("nan"), n_envs: int = 1, bad_env: int = 0):
    def wrapper(env: gym.Env, index: int) -> gym.Env:
        return BadRewardAt(env, step, value) if index == bad_env else env

    envs = [(lambda index=index: wrapper(gym.make("CartPole-v1"), index)) for index in range(n_envs)]
    from stable_baselines3.common.vec_env import DummyVecEnv

    return DummyVecEnv(envs)


MODELS = {
    "offon_dqn_lambda": lambda env, **kw: OffOnDQN("MlpPolicy", env, **SMALL, **kw),
    "offon_dqn_coin_flips": lambda env, **kw: OffOnDQN("MlpPolicy", env, mc_mixing="sample", **SMALL, **kw),
    "offon_qrdqn": lambda env, **kw: OffOnQRDQN("MlpPolicy", env, policy_kwargs=dict(n_quantiles=5), **SMALL, **kw),
    "qrdqn": lambda env, **kw: QRDQN("MlpPolicy", env, policy_kwargs=dict(n_quantiles=5), **SMALL, **kw),
}


def stored(model) -> int:
    buffer = model.replay_buffer
    return buffer.buffer_size if buffer.full else buffer.pos


@pytest.mark.parametrize("name", list(MODELS))
@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_a_non_finite_reward_stops_training_at_its_step(name: str, value: float) -> None:
    model = MODELS[name](cartpole(300, value))
    with pytest.raises(NonFiniteError, match=rf"reward {value} from env 0 at step 300: nothing of this step was stored"):
        model.learn(1_000)
    assert stored(model) == 299
    assert all(th.isfinite(parameter).all() for parameter in model.policy.parameters())


def test_the_error_names_the_env_among_several() -> None:
    model = OffOnDQN("MlpPolicy", cartpole(150, float("nan"), n_envs=3, bad_env=2), **SMALL)
    # The third env's 150th step is the run's vectorised step 150, counted over 3 envs: step 450
    with pytest.raises(NonFiniteError, match=r"reward nan from env 2 at step 450"):
        model.learn(1_000)
    assert stored(model) == 149


def test_the_callback_stops_sb3s_dqn_before_it_stores_the_step() -> None:
    model = DQN("MlpPolicy", cartpole(300), **SMALL)
    with pytest.raises(NonFiniteError, match=r"reward nan from env 0 at step 300"):
        model.learn(1_000, callback=NonFiniteCheck())
    assert model.replay_buffer.pos == 299
    assert all(th.isfinite(parameter).all() for parameter in model.policy.parameters())


def test_without_the_checks_a_nan_reward_poisons_sb3s_dqn() -> None:
    # What the checks prevent: SB3's DQN trains on and every parameter it touches becomes NaN
    model = DQN("MlpPolicy", cartpole(300), **SMALL)
    model.learn(1_000)
    assert not all(th.isfinite(parameter).all() for parameter in model.policy.parameters())


def test_non_finite_rewards_message() -> None:
    assert non_finite_rewards(np.array([0.0, 1.0]), 10) is None
    message = non_finite_rewards(np.array([0.0, -np.inf, np.nan]), 12)
    assert message == "reward -inf from env 1, reward nan from env 2 at step 12"


@pytest.mark.parametrize("name", ["offon_dqn_lambda", "offon_qrdqn"])
def test_skip_stores_nothing_of_the_step_and_cuts_the_episode(name: str) -> None:
    # gamma 0.5, episodes of 10 steps of reward 1; the 14th step's reward is NaN: the second episode's first 3 steps are
    # stored, then cut as a truncation ("terminal": nothing after the cut), and a new segment starts at step 15
    env = make_vec_env(lambda: BadRewardAt(Corridor(10), 14, float("nan")), n_envs=1)
    model = MODELS[name](env, non_finite="skip", gamma=0.5, mc_truncation="terminal")
    with pytest.warns(UserWarning, match=r"reward nan from env 0 at step 14: the step's transitions skipped"):
        model.learn(32)  # 8 rollouts of train_freq 4
    buffer = model.replay_buffer
    assert buffer.pos == 31
    observations = buffer.observations[:31, 0, 0]
    # Slots 10-12 hold steps 11-13 (observations 0, 1, 2 of the second episode), slot 13 step 15 (observation 4)
    np.testing.assert_array_equal(observations[10:14], [0.0, 1.0, 2.0, 4.0])
    assert buffer.dones[12, 0] and buffer.timeouts[12, 0]
    np.testing.assert_allclose(buffer.mc_returns[10:13, 0], [1 + 0.5 + 0.25, 1 + 0.5, 1.0])
    # The segment after the skip ends with its episode (6 steps to the terminal state, observations 4..9)
    np.testing.assert_allclose(buffer.mc_returns[13:19, 0], [sum(0.5**k for k in range(n)) for n in range(6, 0, -1)])
    assert all(th.isfinite(parameter).all() for parameter in model.policy.parameters())


def test_skip_on_sb3s_buffer_marks_the_cut() -> None:
    env = make_vec_env(lambda: BadRewardAt(Corridor(10), 14, float("nan")), n_envs=1)
    model = QRDQN("MlpPolicy", env, policy_kwargs=dict(n_quantiles=5), **SMALL)
    model.non_finite = "skip"
    with pytest.warns(UserWarning, match="skipped"):
        model.learn(32)  # 8 rollouts of train_freq 4
    assert model.replay_buffer.pos == 31
    assert model.replay_buffer.dones[12, 0] and model.replay_buffer.timeouts[12, 0]


@pytest.mark.parametrize("name", list(MODELS))
def test_a_non_finite_loss_stops_training_at_its_training_call(name: str) -> None:
    model = MODELS[name](make_vec_env("CartPole-v1", n_envs=1))
    model.learn(60)  # past learning_starts: it has trained
    with th.no_grad():
        next(model.policy.parameters()).fill_(float("nan"))
    with pytest.raises(NonFiniteError, match=r"training loss nan at step 6\d"):
        model.learn(20, reset_num_timesteps=False)


@pytest.mark.parametrize("algo", [OffOnDQN, OffOnQRDQN])
def test_with_prioritised_replay_a_non_finite_error_is_no_priority(algo) -> None:
    model = algo("MlpPolicy", "CartPole-v1", replay_buffer_class=PrioritizedOffOnReplayBuffer, **SMALL)
    model.learn(60)
    with th.no_grad():
        next(model.policy.parameters()).fill_(float("nan"))
    with pytest.raises(NonFiniteError, match=r"Non-finite training error \(NaN or inf\) for a priority: the values diverged"):
        model.learn(20, reset_num_timesteps=False)


def test_non_finite_must_be_an_option() -> None:
    with pytest.raises(ValueError, match=r"`non_finite` must be one of \('raise', 'skip'\), got 'ignore'"):
        OffOnDQN("MlpPolicy", "CartPole-v1", non_finite="ignore")
    with pytest.raises(ValueError, match=r"`non_finite` must be one of"):
        OffOnQRDQN("MlpPolicy", "CartPole-v1", non_finite=None)


@pytest.mark.parametrize("size", [0, -5])
@pytest.mark.parametrize("algo", [OffOnDQN, OffOnQRDQN, QRDQN])
def test_buffer_size_below_one_is_refused(algo, size: int) -> None:
    with pytest.raises(ValueError, match=rf"`buffer_size` must be a positive integer, got {size}"):
        algo("MlpPolicy", "CartPole-v1", buffer_size=size)


@pytest.mark.parametrize("algo", [OffOnQRDQN, QRDQN])
def test_n_quantiles_below_one_is_refused(algo) -> None:
    with pytest.raises(ValueError, match=r"`n_quantiles` must be a positive integer, got 0"):
        algo("MlpPolicy", "CartPole-v1", policy_kwargs=dict(n_quantiles=0))


@pytest.mark.parametrize("algo", ["dqn", "offon_dqn", "qrdqn"])
def test_the_command_line_stops_with_one_line_and_saves_nothing(
    algo: str, tmp_path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    import sys

    from sb3_offon.train import main

    env_id = "NaNRewardAt300CartPole-v1"
    if env_id not in gym.registry:
        gym.register(env_id, entry_point=lambda **kwargs: BadRewardAt(gym.make("CartPole-v1", **kwargs), 300, float("nan")))
    config = tmp_path / "settings.yml"
    config.write_text(f"{env_id}:\n  n_timesteps: 1000\n  policy: MlpPolicy\n  learning_starts: 100\n")
    argv = ["sb3_offon.train", "--algo", algo, "--env", env_id, "-conf", str(config), "-f", str(tmp_path / "logs")]
    monkeypatch.setattr(sys, "argv", [*argv, "--eval-freq", "200", "--checkpoint-freq", "200"])
    with pytest.raises(SystemExit) as raised:
        main()
    assert raised.value.code == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("python -m sb3_offon.train: error: Non-finite reward nan from env 0 at step 300"), line
    (run,) = (tmp_path / "logs" / algo).iterdir()
    # What was saved (the best model of the evaluation at step 200, the checkpoint of step 200) came before the NaN
    from sb3_offon.resume import Checkpoint
    from sb3_offon.zoo import ALGOS

    saved = sorted(run.rglob("*.zip"))
    assert not (run / f"{env_id}.zip").exists(), "the zoo's final model is not saved"
    assert Checkpoint.latest(run / "checkpoint").num_timesteps == 200
    for path in saved:
        model = ALGOS.get(algo, DQN).load(path)
        assert all(th.isfinite(parameter).all() for parameter in model.policy.parameters()), path
