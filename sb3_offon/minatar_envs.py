"""
The five MinAtar games (Young & Tian, "MinAtar: An Atari-Inspired Testbed for Thorough and Reproducible Reinforcement
Learning Experiments", 2019), registered in Gymnasium when ``sb3_offon`` is imported, under the ids of MinAtar's own
Gymnasium module: ``MinAtar/{Asterix,Breakout,Freeway,Seaquest,SpaceInvaders}-v0`` with the full action set of six
actions (as in the MinAtar paper) and ``-v1`` with each game's minimal action set.

MinAtar itself is an optional extra (``pip install -e ".[minatar]"`` in a clone, ``pip install "sb3-offon[minatar]"``
from an index). The ids are registered whether or not it is installed, so that ``gym.make`` on one of them without it
ends with an error naming the extra rather than "environment not found". Under Gymnasium 1.x, MinAtar's own
``minatar.gym.register_envs()`` must be called by hand; this module does it for the user, with two differences:

- The entry point is :func:`make_minatar`, a string into this module, so that an id sent to a ``SubprocVecEnv`` worker
  with its module (``"sb3_offon:MinAtar/Breakout-v0"``) is found there, as for the paper's tasks (see
  :mod:`sb3_offon.envs`).
- A time limit of :data:`MINATAR_MAX_EPISODE_STEPS` steps. MinAtar's games have none of their own apart from Freeway
  (2,500 steps), and a greedy policy that never dives in Seaquest plays a game that never ends: an evaluation of such
  a policy would never return. The limit is four times Freeway's length; a time-limit end is a truncation, which
  every algorithm here bootstraps through, so the games' values are unchanged wherever it does not bind.

Sticky actions (probability 0.1) and difficulty ramping are MinAtar's defaults; ``gym.make(id, sticky_action_prob=0.0)``
or ``difficulty_ramping=False`` (or ``env_kwargs`` on the command line) change them. Observations are the games'
10 x 10 x C boolean grids, channels last; :class:`sb3_offon.MinAtarCNN` is the MinAtar paper's network for them.
If MinAtar's own registration ran first (``minatar.gym.register_envs()`` before ``import sb3_offon``), its entries are
kept.
"""

import warnings
from typing import Any

import gymnasium as gym

MINATAR_GAMES = {
    "Asterix": "asterix",
    "Breakout": "breakout",
    "Freeway": "freeway",
    "Seaquest": "seaquest",
    "SpaceInvaders": "space_invaders",
}
MINATAR_MAX_EPISODE_STEPS = 10_000
INSTALL_HINT = 'pip install -e ".[minatar]" in a clone of the source, or pip install "sb3-offon[minatar]"'


class MinAtarNotInstalledError(ModuleNotFoundError):
    """A ``MinAtar/*`` id made without MinAtar installed; the message names the extra that brings it (the command line
    prints it as one line)."""


def minatar_ids(versions: tuple[str, ...] = ("v0", "v1")) -> list[str]:
    """The registered ids, ``MinAtar/Asterix-v0`` first: by game, each with the requested versions."""
    return [f"MinAtar/{name}-{version}" for name in MINATAR_GAMES for version in versions]


def make_minatar(game: str, use_minimal_action_set: bool = False, **kwargs: Any) -> gym.Env:
    """
    Entry point of the ``MinAtar/*`` ids: MinAtar's own Gymnasium environment (``minatar.gym.BaseEnv``).

    :param game: MinAtar's name of the game (``"space_invaders"``)
    :param use_minimal_action_set: the game's minimal action set (``-v1``) instead of all six actions (``-v0``)
    :param kwargs: the other keyword arguments of ``BaseEnv`` (``render_mode``, ``sticky_action_prob``,
        ``difficulty_ramping``)
    :return: the environment (``gym.make`` adds the time limit around it)
    :raises MinAtarNotInstalledError: when MinAtar is not installed, naming the extra that brings it
    """
    try:
        from minatar.gym import BaseEnv
    except ModuleNotFoundError as error:
        # Not MinAtar itself (one of its own dependencies, say): a broken install, whose traceback says more
        if error.name is None or error.name.partition(".")[0] != "minatar":
            raise
        raise MinAtarNotInstalledError(
            f"The MinAtar games need the optional 'minatar' dependencies (module 'minatar' is missing): {INSTALL_HINT}",
            name="minatar",
        ) from None
    return BaseEnv(game, use_minimal_action_set=use_minimal_action_set, **kwargs)


def register_minatar_envs() -> None:
    """Register the ten ids; an id already registered (a second call, MinAtar's own registration) is left as it is."""
    for name, game in MINATAR_GAMES.items():
        for version, minimal in (("v0", False), ("v1", True)):
            env_id = f"MinAtar/{name}-{version}"
            if env_id in gym.registry:
                continue
            gym.register(
                id=env_id,
                entry_point="sb3_offon.minatar_envs:make_minatar",
                kwargs=dict(game=game, use_minimal_action_set=minimal),
                max_episode_steps=MINATAR_MAX_EPISODE_STEPS,
            )


# Gymnasium takes -v0 and -v1 for two versions of one game and, on each make of a -v0 id, warns that it "is out of
# date" and to upgrade to v1. Here (as in MinAtar's own registration) the two are different action sets of the same
# game, neither newer: the warning would be wrong.
warnings.filterwarnings("ignore", message=r".*The environment MinAtar/\w+-v0 is out of date", category=DeprecationWarning)
register_minatar_envs()
