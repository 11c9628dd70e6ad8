"""
The command line's checks of a run's setup, before anything is built: hyperparameter names against the algorithm's
arguments, the env's action space against the algorithm, the settings a bundled file falls back to; and the errors,
warning and interruption the command line reports in one line (:mod:`sb3_offon.train`).
"""

import difflib
import inspect
import json
import traceback
from pathlib import Path
from typing import Any

import rl_zoo3.exp_manager as zoo_exp_manager
import sb3_contrib
import yaml
from gymnasium import spaces
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_offon.resume import checkpoint_folders

HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"


# Keys of a YAML entry (or --hyperparams) that the zoo itself reads, the rest being the algorithm's keyword arguments
ZOO_KEYS = frozenset(
    {
        "n_timesteps", "n_envs", "normalize", "policy", "env_wrapper", "vec_env_wrapper", "frame_stack", "callback",
        "monitor_kwargs", "env_kwargs", "noise_type", "noise_std",
    }
)  # fmt: skip


# Keys of this package's settings files that are neither the zoo's nor the algorithm's: how the run is evaluated
# (OffOnExperimentManager takes them out before the model is made; the Atari 100k settings use them)
EVALUATION_KEYS = frozenset({"eval_exploration_rate", "eval_env_wrapper", "final_eval_episodes"})


class AtariSettingsNote(UserWarning):
    """What the command line set so that an Atari id runs as its settings expect (an ``ALE/<Game>-v5`` id's frame skip)."""


class UnknownHyperparameterError(ValueError):
    """A hyperparameter (YAML entry or ``--hyperparams``) that is neither the zoo's nor an argument of the algorithm."""


class HyperparameterError(ValueError):
    """A ``ValueError`` the algorithm's constructor raised for the hyperparameters it was given."""


class UnsupportedActionSpaceError(ValueError):
    """An env whose action space the algorithm cannot take (a continuous env for a DQN-family algorithm)."""


class DefaultHyperparametersWarning(UserWarning):
    """A run on settings that were not made for its env: the ``default`` entry of a bundled hyperparameter file."""


class RunInterrupted(KeyboardInterrupt):
    """
    Ctrl-C (or SIGTERM, :mod:`sb3_offon.termination`) during training, raised again once the zoo has saved the model
    trained so far, so that the command line can say where the run stopped and how to go on, and exit with the status of
    an interrupted command.

    A ``KeyboardInterrupt``, so that whatever does not know it treats it as the interruption it is.

    :param num_timesteps: the env step the run reached
    :param budget: the env steps it was to train (``-n`` or the YAML's ``n_timesteps``)
    :param save_path: the run's log folder, where the zoo saved the model
    :param checkpoint_dir: where its checkpoints go (None without ``--checkpoint-freq``)
    :param checkpoint_freq: env steps between checkpoints (0: none)
    :param terminated: whether SIGTERM stopped it (:mod:`sb3_offon.termination`), not Ctrl-C
    """

    def __init__(
        self,
        num_timesteps: int,
        budget: int,
        save_path: str,
        checkpoint_dir: str | None,
        checkpoint_freq: int,
        terminated: bool = False,
    ) -> None:
        super().__init__(f"{'stopped by SIGTERM' if terminated else 'interrupted'} at step {num_timesteps} of {budget}")
        self.num_timesteps = num_timesteps
        self.budget = budget
        self.save_path = save_path
        self.checkpoint_dir = checkpoint_dir
        self.checkpoint_freq = checkpoint_freq
        self.terminated = terminated


# The algorithm families that take only a Discrete action space (SB3 checks it only when the model is built, with an
# AssertionError's traceback). The zoo's other algorithms are left to SB3's check
DISCRETE_ONLY: tuple[type[BaseAlgorithm], ...] = (DQN, sb3_contrib.QRDQN)


def check_action_space(algo: str, algo_class: type, env_id: str, action_space: spaces.Space) -> None:
    """
    :param algo: the ``--algo`` name
    :param algo_class: the class it trains
    :param env_id: the env's id
    :param action_space: the env's action space, as the algorithm would get it (after the env's wrappers)
    :raises UnsupportedActionSpaceError: in a line, when ``algo_class`` is of the DQN family (:data:`DISCRETE_ONLY`)
        and the action space is not ``Discrete``
    """
    if not issubclass(algo_class, DISCRETE_ONLY) or isinstance(action_space, spaces.Discrete):
        return
    kind = " (continuous)" if isinstance(action_space, spaces.Box) else ""
    raise UnsupportedActionSpaceError(
        f"{env_id} has the action space {action_space}{kind}: --algo {algo} ({algo_class.__name__}) needs a Discrete "
        "action space (a finite set of actions); the zoo's ppo, sac and td3 take continuous ones"
    )


# Where the settings bundled with this package and with the zoo are: a run on the `default` entry of one of those files
# is warned about (a file of the user's own that falls back to its `default` does so by the user's design)
ZOO_HYPERPARAMS_DIR = Path(zoo_exp_manager.__file__).resolve().parent / "hyperparams"


def default_settings_note(config: str, env_id: str, is_atari: bool, budget: int) -> str | None:
    """
    What to tell a user whose env has no entry in a bundled hyperparameter file, so that the zoo trains it with the
    file's ``default`` entry: settings that were tuned for no task, usually for a budget of a million steps.

    :param config: the hyperparameter file the zoo read
    :param env_id: the env's id
    :param is_atari: whether the zoo takes the env for an Atari game (it reads the ``atari`` entry then)
    :param budget: the env steps the run trains (``-n``, else the entry's ``n_timesteps``)
    :return: the line to warn with, None when the file has an entry for the env, or is not a bundled one, or the env is
        an Atari game
    """
    path = Path(config).resolve()
    bundled = [folder for folder in (HYPERPARAMS_DIR, ZOO_HYPERPARAMS_DIR) if path.is_relative_to(folder)]
    if path.suffix not in (".yml", ".yaml") or not bundled:
        return None
    with open(path) as file:
        entries = yaml.safe_load(file) or {}
    # The zoo reads an Atari game's settings from the `atari` entry, never from `default`
    if env_id in entries or is_atari or "default" not in entries:
        return None
    # Named from its package (sb3_offon/hyperparams/offon_dqn.yml): the installed path is in the zoo's output above
    shown = path.relative_to(bundled[0].parent.parent).as_posix()
    close = difflib.get_close_matches(env_id, [name for name in entries if name not in ("default", "atari")], n=2)
    hint = f" (closest entries: {', '.join(close)})" if close else ""
    return (
        f"{shown} has no settings for {env_id}: training with its 'default' entry (untuned) for {budget:,} steps{hint}. "
        "Choose the budget with -n, the settings with --hyperparams key:value or -conf FILE"
    )


def raised_by_a_constructor(error: BaseException) -> bool:
    """Whether ``error`` was raised while an algorithm was being built (a frame of ``__init__`` of a ``BaseAlgorithm``)."""
    frame_and_lines = traceback.walk_tb(error.__traceback__)
    return any(
        frame.f_code.co_name == "__init__" and isinstance(frame.f_locals.get("self"), BaseAlgorithm)
        for frame, _ in frame_and_lines
    )


def constructor_arguments(algo_class: type) -> set[str] | None:
    """
    The keyword arguments ``algo_class(...)`` takes: its ``__init__``'s, and its bases' as far as each passes
    ``**kwargs`` on (None when every ``__init__`` up to ``object`` takes ``**kwargs``: anything may be valid).
    """
    names: set[str] = set()
    for klass in algo_class.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None or klass is object:
            continue
        parameters = inspect.signature(init).parameters.values()
        names |= {p.name for p in parameters if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
        if not any(p.kind == p.VAR_KEYWORD for p in parameters):
            return names - {"self"}
    return None


def check_hyperparameter_names(algo: str, algo_class: type, hyperparams: dict[str, Any]) -> None:
    """
    :raises UnknownHyperparameterError: naming the first key of ``hyperparams`` that is neither one of :data:`ZOO_KEYS`
        nor one of :data:`EVALUATION_KEYS` nor an argument of ``algo_class``, with the close matches
    """
    arguments = constructor_arguments(algo_class)
    if arguments is None:
        return
    known = arguments | ZOO_KEYS | EVALUATION_KEYS
    for key in hyperparams:
        if key not in known:
            close = difflib.get_close_matches(key, sorted(known), n=3, cutoff=0.6)
            hint = f"close matches: {', '.join(close)}" if close else "no argument is close to it"
            raise UnknownHyperparameterError(
                f"unknown hyperparameter '{key}' for --algo {algo} ({algo_class.__name__}); {hint}"
            )


def comparable(value: Any) -> Any:
    """``value`` as JSON would give it back (tuples as lists, objects by their ``repr``): what checkpoints record."""
    return json.loads(json.dumps(value, default=repr, sort_keys=True))


def checkpoint_folder(resume: str | None) -> str | None:
    """
    The checkpoint folder ``--resume`` names: the folder itself, or, given the log folder of the interrupted run (the
    zoo's ``logs/{algo}/{env}_{n}``), its ``checkpoint/`` sub-folder, where ``--checkpoint-freq`` writes by default.
    """
    if resume is None or checkpoint_folders(resume):
        return resume
    inside = Path(resume) / "checkpoint"
    return str(inside) if checkpoint_folders(inside) else resume
