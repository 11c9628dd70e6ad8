"""The Section 4.4 tasks: rewards, terminations and goal counts on hand-made trajectories."""

import importlib
import warnings

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.monitor import Monitor

import sb3_offon.envs
from sb3_offon.envs import CARTPOLE_FALL_PENALTY_ID, MOUNTAINCAR_GOAL_BONUS_ID, register_envs

# Pushing the cart in one direction makes the pole fall within a few dozen steps
PUSH_RIGHT = 1
NO_PUSH = 1


def rollout(env: gym.Env, policy, seed: int, max_steps: int = 1000) -> dict[str, list]:
    """Run one episode with ``policy(obs) -> action``: every step's observation, reward, flags and info."""
    obs, _ = env.reset(seed=seed)
    steps: dict[str, list] = {"obs": [obs], "rewards": [], "terminated": [], "truncated": [], "infos": []}
    for _ in range(max_steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        steps["obs"].append(obs)
        steps["rewards"].append(float(reward))
        steps["terminated"].append(terminated)
        steps["truncated"].append(truncated)
        steps["infos"].append(info)
        if terminated or truncated:
            return steps
    raise AssertionError(f"no episode end within {max_steps} steps")


def energy_pumping(obs: np.ndarray) -> int:
    """Push in the direction of the velocity: reaches MountainCar's goal in about a hundred steps."""
    return 2 if obs[1] >= 0 else 0


def test_registered_once() -> None:
    assert gym.spec(CARTPOLE_FALL_PENALTY_ID).max_episode_steps == 500
    assert gym.spec(MOUNTAINCAR_GOAL_BONUS_ID).max_episode_steps == 200
    with warnings.catch_warnings():
        # Gymnasium warns when an id is registered again: a second registration (or import) must not do it
        warnings.simplefilter("error")
        register_envs()
        importlib.reload(sb3_offon.envs)


def test_fall_penalty_replaces_the_last_reward() -> None:
    penalized = rollout(gym.make(CARTPOLE_FALL_PENALTY_ID), lambda _: PUSH_RIGHT, seed=3)
    original = rollout(gym.make("CartPole-v1"), lambda _: PUSH_RIGHT, seed=3)
    n_steps = len(original["rewards"])
    assert 1 < n_steps < 500
    # Same dynamics, same episode; only the reward of the fall differs
    np.testing.assert_array_equal(np.array(penalized["obs"]), np.array(original["obs"]))
    assert penalized["rewards"] == [1.0] * (n_steps - 1) + [-100.0]
    assert penalized["terminated"] == [False] * (n_steps - 1) + [True]
    assert penalized["truncated"] == [False] * n_steps


def test_fall_penalty_value_is_a_kwarg() -> None:
    steps = rollout(gym.make(CARTPOLE_FALL_PENALTY_ID, fall_reward=-7.5), lambda _: PUSH_RIGHT, seed=3)
    assert steps["rewards"][-1] == -7.5
    assert set(steps["rewards"][:-1]) == {1.0}


def test_time_limit_is_not_penalized() -> None:
    # Alternating pushes keep the pole up for 20 steps: the episode is cut by the time limit, not by a fall
    actions = iter([0, 1] * 10)
    steps = rollout(gym.make(CARTPOLE_FALL_PENALTY_ID, max_episode_steps=20), lambda _: next(actions), seed=0)
    assert steps["rewards"] == [1.0] * 20
    assert steps["terminated"] == [False] * 20
    assert steps["truncated"] == [False] * 19 + [True]


def test_fall_on_the_last_step_is_penalized() -> None:
    n_steps = len(rollout(gym.make("CartPole-v1"), lambda _: PUSH_RIGHT, seed=3)["rewards"])
    # A time limit equal to the fall's step. Gymnasium's TimeLimit flags it as truncated too, the one rl_zoo3 patches
    # in on import does not: either way the fall terminates the episode and is penalised
    steps = rollout(gym.make(CARTPOLE_FALL_PENALTY_ID, max_episode_steps=n_steps), lambda _: PUSH_RIGHT, seed=3)
    assert len(steps["rewards"]) == n_steps
    assert steps["terminated"][-1]
    assert steps["rewards"][-1] == -100.0


def test_monitor_return_of_a_fall() -> None:
    env = Monitor(gym.make(CARTPOLE_FALL_PENALTY_ID))
    steps = rollout(env, lambda _: PUSH_RIGHT, seed=5)
    n_steps = len(steps["rewards"])
    episode = steps["infos"][-1]["episode"]
    assert episode["l"] == n_steps
    assert episode["r"] == pytest.approx((n_steps - 1) - 100.0)


def test_goal_bonus_and_count() -> None:
    env = gym.make(MOUNTAINCAR_GOAL_BONUS_ID)
    original = rollout(gym.make("MountainCar-v0"), energy_pumping, seed=0)
    steps = rollout(env, energy_pumping, seed=0)
    n_steps = len(steps["rewards"])
    assert n_steps == len(original["rewards"]) < 200
    np.testing.assert_array_equal(np.array(steps["obs"]), np.array(original["obs"]))
    assert steps["obs"][-1][0] >= 0.5
    assert steps["rewards"] == [-1.0] * (n_steps - 1) + [150.0]
    assert steps["terminated"] == [False] * (n_steps - 1) + [True]
    assert [info["goal_reached"] for info in steps["infos"]] == [False] * (n_steps - 1) + [True]
    assert env.get_wrapper_attr("goal_count") == 1

    # An episode that never pushes ends by the time limit: no bonus, no goal, and the count survives the reset
    idle = rollout(env, lambda _: NO_PUSH, seed=1)
    assert idle["rewards"] == [-1.0] * 200
    assert idle["terminated"] == [False] * 200
    assert idle["truncated"] == [False] * 199 + [True]
    assert not any(info["goal_reached"] for info in idle["infos"])
    assert env.get_wrapper_attr("goal_count") == 1

    rollout(env, energy_pumping, seed=2)
    assert env.get_wrapper_attr("goal_count") == 2


def test_goal_bonus_value_is_a_kwarg() -> None:
    steps = rollout(gym.make(MOUNTAINCAR_GOAL_BONUS_ID, goal_reward=10.0), energy_pumping, seed=0)
    assert steps["rewards"][-1] == 10.0


def test_goal_flag_reaches_the_monitor() -> None:
    env = Monitor(gym.make(MOUNTAINCAR_GOAL_BONUS_ID), info_keywords=("goal_reached",))
    steps = rollout(env, energy_pumping, seed=0)
    n_steps = len(steps["rewards"])
    assert steps["infos"][-1]["episode"]["goal_reached"] is True
    assert steps["infos"][-1]["episode"]["r"] == pytest.approx(150.0 - (n_steps - 1))
    idle = rollout(env, lambda _: NO_PUSH, seed=1)
    assert idle["infos"][-1]["episode"]["goal_reached"] is False
