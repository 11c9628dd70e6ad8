"""
Atari games (through ``ale-py``, the optional ``atari`` extra) as the Atari 100k protocol plays them.

- :func:`register_atari_envs`: the ALE's ids (``BreakoutNoFrameskip-v4``, ``ALE/Breakout-v5``, ...) registered in
  Gymnasium when ``sb3_offon`` is imported and ``ale-py`` is installed, so that ``OffOnDQN("CnnPolicy",
  "BreakoutNoFrameskip-v4")`` works as the command line does (the zoo registers them for its own commands only).
- :class:`AtariEvaluationWrapper`: the evaluation games of the protocol: SB3's ``AtariWrapper`` preprocessing without
  the end of an episode on a life lost, so that an evaluation episode is a whole game.
- :func:`ale_v5_kwargs`: the arguments that make an ``ALE/<Game>-v5`` id what SB3's ``AtariWrapper`` expects.

The protocol (Kaiser et al., "Model-Based Reinforcement Learning for Atari", 2019; the settings of Dopamine's
``atari_100k`` and of Data-Efficient Rainbow) is bundled as the hyperparameter set ``atari100k``
(``sb3_offon/hyperparams/atari100k/``, ``-conf atari100k`` on the command line): 100,000 agent steps on
``<Game>NoFrameskip-v4`` under ``AtariWrapper`` (up to 30 no-ops, frame skip 4 with max-pooling, 84 x 84 grey, rewards
clipped, end of episode on a life lost while training), 4 stacked frames, no sticky actions, at most 108,000 frames
(27,000 agent steps) a game (the ALE's own limit on these ids); evaluation with epsilon 0.001 on whole games.
"""

from typing import Any, SupportsFloat

import gymnasium as gym
from stable_baselines3.common.atari_wrappers import FireResetEnv, MaxAndSkipEnv, NoopResetEnv, WarpFrame

# What AtariWrapper does itself, and so what an ALE/<Game>-v5 id must not do again under it
V5_UNDER_ATARI_WRAPPER = {"frameskip": 1, "repeat_action_probability": 0.0}


def register_atari_envs() -> bool:
    """
    Register the ALE's ids in Gymnasium (``gym.register_envs(ale_py)``) when ``ale-py`` is installed.

    :return: whether they are registered
    """
    try:
        import ale_py
    except ImportError:
        return False
    gym.register_envs(ale_py)
    return True


def looks_like_atari(env_id: str) -> bool:
    """Whether ``env_id`` is written as one of the ALE's ids (``ALE/...-v5``, ``...NoFrameskip-v4``, ``...-v0``/``-v4``)."""
    return env_id.startswith("ALE/") or "NoFrameskip" in env_id


def ale_v5_kwargs(env_id: str, env_kwargs: dict[str, Any]) -> tuple[dict[str, Any], str | None]:
    """
    The env's arguments for a run under SB3's ``AtariWrapper``: an ``ALE/<Game>-v5`` id skips 4 frames a step and
    repeats the previous action with probability 0.25 by itself, so under ``AtariWrapper`` (which skips 4 frames
    itself) each agent step would be 16 frames. ``frameskip=1`` and ``repeat_action_probability=0`` make it the
    ``<Game>NoFrameskip-v4`` game, where the user has not set them.

    :param env_id: the env id
    :param env_kwargs: the run's env arguments
    :return: the arguments to make the env with, and a line saying what was set (None: nothing)
    """
    if not env_id.startswith("ALE/"):
        return env_kwargs, None
    added = {key: value for key, value in V5_UNDER_ATARI_WRAPPER.items() if key not in env_kwargs}
    if not added:
        return env_kwargs, None
    settings = ", ".join(f"{key}={value}" for key, value in added.items())
    line = (
        f"{env_id} under AtariWrapper: {settings} set (AtariWrapper skips 4 frames itself; the Atari settings have no "
        "sticky actions), which makes it the NoFrameskip-v4 game; --env-kwargs sets them otherwise"
    )
    return {**env_kwargs, **added}, line


class FireAfterLifeLossEnv(gym.Wrapper):
    """
    After a life is lost (the game going on), take the steps that SB3's ``AtariWrapper`` takes at the start of each
    training episode (no-op, FIRE, then the action after FIRE, as ``EpisodicLifeEnv.reset`` and ``FireResetEnv.reset``
    do), their rewards added to the step's.

    Why: training under ``AtariWrapper`` ends an episode at each life lost, and the next one starts with FIRE pressed by
    the wrapper; an agent so trained never learns to press FIRE itself. Played as a whole game, without these steps,
    Breakout would wait for the serve after the first life lost until a random action (probability 0.001 each step)
    happened to be FIRE. With them, every life starts as every training episode did.

    :param env: the game, with frame skipping below this wrapper (each step one agent step)
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.lives = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self.lives = self.env.unwrapped.ale.lives()  # type: ignore[attr-defined]
        return obs, info

    def step(self, action: int) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        total = float(reward)
        lives = self.env.unwrapped.ale.lives()  # type: ignore[attr-defined]
        if 0 < lives < self.lives:
            for follow_up in (0, 1, 2):
                if terminated or truncated:
                    break
                obs, reward, terminated, truncated, info = self.env.step(follow_up)
                total += float(reward)
        self.lives = lives
        return obs, total, terminated, truncated, info


class AtariEvaluationWrapper(gym.Wrapper):
    """
    The evaluation games of the Atari 100k protocol: SB3's ``AtariWrapper`` preprocessing (up to ``noop_max`` no-ops at
    the start, ``frame_skip`` frames a step with max-pooling, FIRE at the start where the game has it, ``screen_size``
    square grey frames) on whole games: no end of episode on a life lost (:class:`FireAfterLifeLossEnv` starts each new
    life as training episodes start), rewards not clipped. Used by the ``atari100k`` settings as the evaluation env's
    wrapper (``eval_env_wrapper``); the scores are those of the ``Monitor`` beneath, whole games either way.

    :param env: the game (``<Game>NoFrameskip-v4``)
    :param noop_max: the most no-ops at the start of a game
    :param frame_skip: frames a step
    :param screen_size: the side of the frames
    """

    def __init__(self, env: gym.Env, noop_max: int = 30, frame_skip: int = 4, screen_size: int = 84) -> None:
        if noop_max > 0:
            env = NoopResetEnv(env, noop_max=noop_max)
        if frame_skip > 1:
            env = MaxAndSkipEnv(env, skip=frame_skip)
        action_meanings = env.unwrapped.get_action_meanings()  # type: ignore[attr-defined]
        if "FIRE" in action_meanings:
            env = FireAfterLifeLossEnv(env)
            env = FireResetEnv(env)
        env = WarpFrame(env, width=screen_size, height=screen_size)
        super().__init__(env)


register_atari_envs()
