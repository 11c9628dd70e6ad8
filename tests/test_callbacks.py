"""The training callbacks, on envs whose episodes are known in advance."""

import csv
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3 import DQN
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure

from sb3_offon.callbacks import GoalCountCallback, StopOnMeanTrainingReward


class FixedEpisodeEnv(gym.Env):
    """
    Episodes of ``length`` steps, each step worth ``reward``; the last step flags a goal reach.

    :param length: the number of steps of every episode
    :param reward: the reward of every step
    """

    def __init__(self, length: int = 5, reward: float = 2.0) -> None:
        self.observation_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_space = spaces.Discrete(2)
        self.length = length
        self.reward = reward
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(2, dtype=np.float32), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.t += 1
        terminated = self.t == self.length
        return np.zeros(2, dtype=np.float32), self.reward, terminated, False, {"goal_reached": terminated}


def make_model(n_envs: int = 1) -> DQN:
    env = make_vec_env(FixedEpisodeEnv, n_envs=n_envs, seed=0)
    # No gradient step: only the callbacks are under test
    return DQN("MlpPolicy", env, learning_starts=10_000, buffer_size=1000, seed=0)


@pytest.mark.parametrize(
    "threshold, episode_key, n_envs, stopped_at",
    [
        # Mean return 10 from the first episode, but a full window of 3 episodes is awaited: 3 x 5 steps
        (10.0, "r", 1, 15),
        # Two envs end an episode together: 4 episodes (>= 3) after 2 x 5 steps, i.e. 20 timesteps
        (10.0, "r", 2, 20),
        # The length (5) instead of the return (10)
        (5.0, "l", 1, 15),
    ],
)
def test_stop_on_mean_training_reward(threshold: float, episode_key: str, n_envs: int, stopped_at: int) -> None:
    model = make_model(n_envs)
    callback = StopOnMeanTrainingReward(threshold=threshold, window=3, episode_key=episode_key)
    model.learn(200, callback=callback)
    assert callback.stopped_at == stopped_at
    assert model.num_timesteps == stopped_at
    assert callback.n_episodes == stopped_at // 5
    assert list(callback.recent) == [10.0 if episode_key == "r" else 5.0] * 3


def test_no_stop_below_threshold() -> None:
    model = make_model()
    callback = StopOnMeanTrainingReward(threshold=10.5, window=3)
    model.learn(100, callback=callback)
    assert callback.stopped_at is None
    assert model.num_timesteps == 100
    assert callback.n_episodes == 20


def test_stop_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="window"):
        StopOnMeanTrainingReward(window=0)
    with pytest.raises(ValueError, match="episode_key"):
        StopOnMeanTrainingReward(episode_key="return")


@pytest.mark.parametrize("n_envs", [1, 2])
def test_goal_count_is_logged(tmp_path, n_envs: int) -> None:
    model = make_model(n_envs)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    callback = GoalCountCallback()
    # 40 timesteps: 40 / 5 = 8 episodes, each ending with a goal reach
    model.learn(40, callback=callback, log_interval=1)
    assert callback.goal_count == 8
    with open(tmp_path / "progress.csv") as file:
        logged = [row["rollout/goal_reached"] for row in csv.DictReader(file)]
    # SB3 dumps the log at each episode end, so twice on a step where both envs end one; the count is recorded once
    # per step, so only the first of those two dumps carries it
    assert len(logged) == 8
    expected = list(range(1, 9)) if n_envs == 1 else list(range(2, 9, 2))
    assert [int(value) for value in logged if value != ""] == expected
