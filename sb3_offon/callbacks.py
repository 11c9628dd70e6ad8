"""
Training callbacks for the tasks of Section 4.4 of the paper.

Both read the per-step ``infos`` of the training env, so they work with any number of envs and need no access to the
env objects; rl-baselines3-zoo builds them from a YAML entry's ``callback:`` key, e.g.::

    callback:
      - sb3_offon.callbacks.StopOnMeanTrainingReward:
          threshold: 490
          window: 100
      - sb3_offon.callbacks.GoalCountCallback

Both keep their running state (``get_state``/``set_state``) in the checkpoints of :mod:`sb3_offon.resume`, so that a
resumed run stops and counts as the uninterrupted one would.
"""

from collections import deque
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sb3_offon.envs import GOAL_REACHED_KEY


class StopOnMeanTrainingReward(BaseCallback):
    """
    Stop training once the mean over the last ``window`` finished training episodes reaches ``threshold``.

    This is the paper's stopping rule on CartPole (Section 4.4: the loop ends once the average over 100 consecutive
    runs reaches 490). It judges training episodes, not a separate evaluation (unlike SB3's
    ``StopTrainingOnRewardThreshold``), and waits for a full window of episodes.
    Episodes are read from the ``info["episode"]`` summaries that ``Monitor`` adds (the zoo and ``make_vec_env``
    always wrap envs in a ``Monitor``). Its own window is kept so that ``window`` is independent of the model's
    ``stats_window_size``.

    :param threshold: the mean at (or above) which training stops
    :param window: the number of most recent finished episodes averaged
    :param episode_key: which ``Monitor`` figure is averaged: ``"r"`` the episode return, ``"l"`` its length
        (on CartPole the length is the return without the fall penalty, which is what the paper's scripts compared
        with 490)
    :param verbose: verbosity level: 0 silent, 1 a message when training is stopped
    """

    def __init__(self, threshold: float = 490.0, window: int = 100, episode_key: str = "r", verbose: int = 0) -> None:
        super().__init__(verbose=verbose)
        if window < 1:
            raise ValueError(f"`window` must be at least 1, got {window}")
        if episode_key not in ("r", "l"):
            raise ValueError(f"`episode_key` must be 'r' (return) or 'l' (length), got {episode_key!r}")
        self.threshold = threshold
        self.window = window
        self.episode_key = episode_key
        self.recent: deque[float] = deque(maxlen=window)
        self.n_episodes = 0
        # The number of timesteps at which training was stopped, None while it runs on
        self.stopped_at: int | None = None

    def get_state(self) -> dict[str, Any]:
        """The window of recent episodes, which a run checkpoint keeps so that a resumed run stops where it would have."""
        return {"recent": list(self.recent), "n_episodes": self.n_episodes}

    def set_state(self, state: dict[str, Any]) -> None:
        """Go on from :meth:`get_state`'s window."""
        self.recent = deque((float(value) for value in state["recent"]), maxlen=self.window)
        self.n_episodes = int(state["n_episodes"])

    def _on_step(self) -> bool:
        finished = False
        for info in self.locals["infos"]:
            episode = info.get("episode")
            if episode is not None:
                self.recent.append(float(episode[self.episode_key]))
                self.n_episodes += 1
                finished = True
        if not finished or len(self.recent) < self.window:
            return True
        mean = float(np.mean(self.recent))
        if mean < self.threshold:
            return True
        self.stopped_at = self.num_timesteps
        if self.verbose >= 1:
            figure = "return" if self.episode_key == "r" else "length"
            print(
                f"Stopping training: mean episode {figure} {mean:.2f} over the last {self.window} episodes "
                f">= {self.threshold} (after {self.n_episodes} episodes, {self.num_timesteps} timesteps)"
            )
        return False


class GoalCountCallback(BaseCallback):
    """
    Count the training steps that reach the goal and log the running count as ``rollout/goal_reached``.

    This is the paper's Figure 16 measure on ``MountainCarGoalBonus-v0`` ("Car has reached the goal" outputs), read
    from the ``info[info_key]`` flag that :class:`sb3_offon.envs.GoalBonusWrapper` sets. The count covers every
    training env and all ``learn()`` calls made with this callback. It is recorded at every step, so each log dump
    (every ``log_interval`` episodes for DQN) carries it; except that SB3 dumps once per finished episode, so when
    several envs end an episode on the same step, only the first of those dumps has it (the others leave it blank).

    :param info_key: the boolean ``info`` entry that flags a goal reach
    :param log_key: the logger key of the running count
    :param verbose: verbosity level: 0 silent, 1 a message at each goal reach
    """

    def __init__(self, info_key: str = GOAL_REACHED_KEY, log_key: str = "rollout/goal_reached", verbose: int = 0) -> None:
        super().__init__(verbose=verbose)
        self.info_key = info_key
        self.log_key = log_key
        self.goal_count = 0

    def get_state(self) -> dict[str, Any]:
        """The count so far, which a run checkpoint keeps so that a resumed run counts on from it."""
        return {"goal_count": self.goal_count}

    def set_state(self, state: dict[str, Any]) -> None:
        """Go on from :meth:`get_state`'s count."""
        self.goal_count = int(state["goal_count"])

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            if info.get(self.info_key, False):
                self.goal_count += 1
                if self.verbose >= 1:
                    print(f"Goal reached ({self.goal_count} so far, at {self.num_timesteps} timesteps)")
        self.logger.record(self.log_key, self.goal_count)
        return True
