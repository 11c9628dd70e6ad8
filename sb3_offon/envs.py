"""
The two tasks of Section 4.4 of the paper ("Cart-Pole and MountainCar with Qualified Upper Bound"), registered in
Gymnasium when ``sb3_offon`` is imported, so that ``--env CartPoleFallPenalty-v1`` works from the command line,
``gym.make`` and ``make_vec_env`` alike.

- ``CartPoleFallPenalty-v1``: CartPole-v1 (500 steps) whose reward is -100 on the step where the pole falls (or the
  cart leaves the track). Pair it with :class:`sb3_offon.callbacks.StopOnMeanTrainingReward` (the paper stops once
  the mean of the last 100 episodes reaches 490).
- ``MountainCarGoalBonus-v0``: MountainCar-v0 (200 steps) whose reward is +150 on the step where the car reaches the
  goal. Each step's ``info["goal_reached"]`` says whether that step reached it, which
  :class:`sb3_offon.callbacks.GoalCountCallback` turns into the running count ``rollout/goal_reached`` (the paper's
  Figure 16) and ``Monitor(info_keywords=("goal_reached",))`` writes into the monitor CSV, one flag per episode.

The entry points are strings into this module (not closures), so that an ``EnvSpec`` sent to a ``SubprocVecEnv``
worker (as rl-baselines3-zoo does) imports this module there. A bare id sent to a fresh worker is not enough: the
worker's registry only knows these ids once this module is imported in it. Outside the zoo, pass the id with its
module, which Gymnasium imports first::

    make_vec_env("sb3_offon.envs:CartPoleFallPenalty-v1", n_envs=4, vec_env_cls=SubprocVecEnv)
"""

from typing import Any, SupportsFloat

import gymnasium as gym
from gymnasium.envs.classic_control import CartPoleEnv, MountainCarEnv

CARTPOLE_FALL_PENALTY_ID = "CartPoleFallPenalty-v1"
MOUNTAINCAR_GOAL_BONUS_ID = "MountainCarGoalBonus-v0"
GOAL_REACHED_KEY = "goal_reached"


class FallPenaltyWrapper(gym.Wrapper):
    """
    Replace the reward of the step on which the episode terminates by a fixed penalty.

    On CartPole, termination means that the pole fell or the cart left the track; a time-limit truncation is not a
    termination and is never penalised. The paper's code base (Keras scripts) could not tell the two apart and skipped
    the penalty on step 500 whatever happened; Gymnasium can, so a fall on step 500 is penalised too: the reward
    then depends on the state only, not on a clock that the agent does not observe.

    The penalty replaces the step's reward (as in ``reward = -100`` of the reference scripts); it is not added to it.

    :param env: the environment to wrap
    :param fall_reward: reward of the terminating step (-100 in the paper)
    """

    def __init__(self, env: gym.Env, fall_reward: float = -100.0) -> None:
        super().__init__(env)
        self.fall_reward = fall_reward

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated:
            reward = self.fall_reward
        return obs, reward, terminated, truncated, info


class GoalBonusWrapper(gym.Wrapper):
    """
    Replace the reward of the step that reaches the goal by a bonus, flag that step in ``info`` and count goal reaches.

    In MountainCar the episode terminates exactly when the car reaches the goal (position >= 0.5 with a non-negative
    velocity), so termination is the goal signal; a time-limit truncation is not a goal reach.
    The bonus replaces the step's reward ("we set the reward +150", Section 4.4); it is not added to the -1.

    Every step's ``info`` carries ``goal_reached`` (a bool) so that ``Monitor(info_keywords=("goal_reached",))`` can
    record it per episode and :class:`sb3_offon.callbacks.GoalCountCallback` can count it across vectorised envs.
    ``goal_count`` is this env's own running count: it survives resets.

    :param env: the environment to wrap
    :param goal_reward: reward of the step that reaches the goal (+150 in the paper)
    """

    def __init__(self, env: gym.Env, goal_reward: float = 150.0) -> None:
        super().__init__(env)
        self.goal_reward = goal_reward
        self.goal_count = 0

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        goal_reached = bool(terminated)
        if goal_reached:
            reward = self.goal_reward
            self.goal_count += 1
        info[GOAL_REACHED_KEY] = goal_reached
        return obs, reward, terminated, truncated, info


def make_cartpole_fall_penalty(render_mode: str | None = None, fall_reward: float = -100.0, **kwargs: Any) -> gym.Env:
    """
    Entry point of ``CartPoleFallPenalty-v1`` (``gym.make`` adds the 500-step time limit around it).

    :param render_mode: passed to ``CartPoleEnv``
    :param fall_reward: reward of the step on which the pole falls
    :param kwargs: other keyword arguments of ``CartPoleEnv`` (``sutton_barto_reward``)
    :return: the wrapped environment
    """
    return FallPenaltyWrapper(CartPoleEnv(render_mode=render_mode, **kwargs), fall_reward=fall_reward)


def make_mountaincar_goal_bonus(render_mode: str | None = None, goal_reward: float = 150.0, **kwargs: Any) -> gym.Env:
    """
    Entry point of ``MountainCarGoalBonus-v0`` (``gym.make`` adds the 200-step time limit around it).

    :param render_mode: passed to ``MountainCarEnv``
    :param goal_reward: reward of the step that reaches the goal
    :param kwargs: other keyword arguments of ``MountainCarEnv`` (``goal_velocity``)
    :return: the wrapped environment
    """
    return GoalBonusWrapper(MountainCarEnv(render_mode=render_mode, **kwargs), goal_reward=goal_reward)


def register_envs() -> None:
    """
    Register the two environments in Gymnasium's registry; a second call (or a second import) does nothing,
    so that Gymnasium's "overriding environment" warning never fires.
    """
    if CARTPOLE_FALL_PENALTY_ID not in gym.registry:
        gym.register(
            id=CARTPOLE_FALL_PENALTY_ID,
            # A literal module path: ``__name__`` would be "__main__" if this file were run as a script
            entry_point="sb3_offon.envs:make_cartpole_fall_penalty",
            max_episode_steps=500,
            # The paper's stop criterion (mean of the last 100 episodes >= 490)
            reward_threshold=490.0,
        )
    if MOUNTAINCAR_GOAL_BONUS_ID not in gym.registry:
        gym.register(
            id=MOUNTAINCAR_GOAL_BONUS_ID,
            entry_point="sb3_offon.envs:make_mountaincar_goal_bonus",
            max_episode_steps=200,
            # MountainCar-v0's -110 moved by the bonus: an episode reaching the goal on step L returns 151 - L,
            # so a mean length of 110 (all goals reached) is a mean return of 41.
            reward_threshold=41.0,
        )


register_envs()
