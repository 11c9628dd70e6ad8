"""
What an algorithm that replays from an Off-On buffer (:mod:`sb3_offon.common.buffers`: episode bookkeeping, next
actions, n-step windows) needs around SB3's off-policy machinery: which buffer class, built with the model's discounting,
a loaded buffer checked against it, episodes cut off by an env reset ended, and a generator of its own for the target
draws. :class:`sb3_offon.OffOnDQN` and :class:`sb3_offon.OffOnQRDQN` share it; it goes right before the algorithm
class (SB3's ``DQN``, sb3-contrib's ``QRDQN``) in their bases.
"""

import inspect
import math
import numbers
import warnings
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import MaybeCallback

from sb3_offon.common.buffers import (
    OffOnBufferMixin,
    OffOnDictReplayBuffer,
    OffOnNStepReplayBuffer,
    OffOnReplayBuffer,
)
from sb3_offon.common.lambda_choice import LAMBDA_CHOICES
from sb3_offon.common.lambda_horizons import lambda_for_horizon

MC_TRUNCATION_OPTIONS = ("bootstrap", "terminal", "drop")


def real_number(name: str, value: Any) -> float:
    """
    ``value`` as a float, if it is a real number: not a string ("0.5"), None, NaN or a bool (``True`` would pass as 1).

    :raises ValueError: naming the parameter, otherwise the comparisons that follow raise a ``TypeError`` (a string)
        or pass silently (NaN, bools)
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) or math.isnan(value):
        raise ValueError(f"`{name}` must be a real number, got {value!r} ({type(value).__name__})")
    return float(value)


def check_option(name: str, value: Any, options: tuple[str, ...]) -> None:
    """:raises ValueError: naming the parameter, unless ``value`` is one of the strings ``options``."""
    # isinstance first: an array or other object would make ``in`` ambiguous or raise something else
    if not isinstance(value, str) or value not in options:
        raise ValueError(f"`{name}` must be one of {options}, got {value!r}")


def check_positive_integer(name: str, value: Any) -> None:
    """
    :raises ValueError: naming the parameter, unless ``value`` is an integer of at least 1 (SB3 would make a buffer of
        one transition from a ``buffer_size`` of 0 or below, and QR-DQN fail at its first gradient step with no quantile)
    """
    if not integer(value) or value < 1:
        raise ValueError(f"`{name}` must be a positive integer, got {value!r}")


def integer(value: Any) -> bool:
    """Whether ``value`` is an integer (NumPy's too), and not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def check_training_arguments(model: Any) -> None:
    """
    Check the off-policy arguments that SB3 takes unchecked, for OffOnDQN, OffOnQRDQN and the package's QRDQN:
    ``batch_size``, ``n_steps``, ``train_freq``, ``gradient_steps``, ``target_update_interval`` and
    ``learning_starts``. Without it, a ``batch_size`` of 0 fails at the first gradient step ("need at least one array to
    concatenate"), an ``n_steps`` of 0 trains silently on nothing, and a negative ``learning_starts`` is taken as 0.
    ``gradient_steps`` may be 0 (no training, SB3's special case) or -1 (as many as env steps in the rollout).

    :raises ValueError: naming the first bad parameter
    """
    for name in ("batch_size", "n_steps", "target_update_interval"):
        check_positive_integer(name, getattr(model, name, 1))  # getattr: SB3 versions before n_steps
    if not integer(model.gradient_steps) or model.gradient_steps < -1:
        raise ValueError(f"`gradient_steps` must be a non-negative integer or -1, got {model.gradient_steps!r}")
    if not integer(model.learning_starts) or model.learning_starts < 0:
        raise ValueError(f"`learning_starts` must be a non-negative integer, got {model.learning_starts!r}")
    # An int, a (frequency, unit) tuple, or SB3's TrainFreq (a loaded model's); the unit is SB3's to check
    frequency = model.train_freq[0] if isinstance(model.train_freq, tuple) else model.train_freq
    if not integer(frequency) or frequency < 1:
        raise ValueError(f"`train_freq` must be a positive integer or a (frequency, unit) tuple, got {model.train_freq!r}")


def check_lambda_arguments(model: Any) -> None:
    """
    Check the arguments that OffOnDQN and OffOnQRDQN share: the delta1 and delta2 schedules, ``mc_truncation``,
    ``double_q``, ``lambda_block_size``, ``lambda_refresh_interval`` and ``lambda_choice``.

    :raises ValueError: naming the first bad parameter
    """
    for name in ("mc_initial_prob", "mc_final_prob", "qlearning_initial_prob", "qlearning_final_prob"):
        value = real_number(name, getattr(model, name))
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"`{name}` must be a probability in [0, 1], got {value!r}")
    for name in ("mc_fraction", "qlearning_fraction"):
        value = real_number(name, getattr(model, name))
        if not 0.0 < value <= 1.0:
            raise ValueError(f"`{name}` must be in (0, 1], got {value!r}")
    check_option("mc_truncation", model.mc_truncation, MC_TRUNCATION_OPTIONS)
    check_option("lambda_choice", model.lambda_choice, LAMBDA_CHOICES)
    # getattr: models saved before double_q existed load without it (and train as before, without double Q)
    if not isinstance(getattr(model, "double_q", False), (bool, np.bool_)):
        raise ValueError(f"`double_q` must be True or False, got {model.double_q!r}")
    check_lambda_horizon(model)
    for name, allow_none in (("lambda_block_size", False), ("lambda_refresh_interval", True)):
        value = getattr(model, name)
        if allow_none and value is None:
            continue
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < 1:
            raise ValueError(f"`{name}` must be a positive integer{' or None' if allow_none else ''}, got {value!r}")


def check_lambda_horizon(model: Any) -> None:
    """
    ``lambda_horizon``: None, or a finite real number of env steps at least ``n_steps`` (a window's length), with
    ``gamma`` below 1, delta1's schedule (``mc_initial_prob``, ``mc_final_prob``) at the constructor's defaults and
    ``lambda_choice="fixed"``: the horizon states lambda for the whole run, and a second statement of it would be
    ambiguous.

    :raises ValueError: naming the bad parameter
    """
    if model.lambda_horizon is None:
        return
    horizon = real_number("lambda_horizon", model.lambda_horizon)
    if not math.isfinite(horizon) or horizon < model.n_steps:
        raise ValueError(
            f"`lambda_horizon` must be a finite number of env steps, at least `n_steps` ({model.n_steps}: a window's "
            f"length), got {model.lambda_horizon!r}"
        )
    if not 0.0 < model.gamma < 1.0:
        raise ValueError(f"`lambda_horizon` needs a discount `gamma` in (0, 1) to contract with, got {model.gamma!r}")
    for name in ("mc_initial_prob", "mc_final_prob"):
        if getattr(model, name) != constructor_default(type(model), name):
            raise ValueError(
                f"`{name}`: `lambda_horizon` ({model.lambda_horizon!r}) states lambda for the whole run; leave "
                "`mc_initial_prob` and `mc_final_prob` at their defaults, or pass lambda through them instead (to tune "
                "lambda, leave `lambda_horizon` out of the settings: the samplers tune it through them)"
            )
    if model.lambda_choice != "fixed":
        raise ValueError(
            f"`lambda_horizon`: `lambda_choice` {model.lambda_choice!r} chooses lambda itself; use `lambda_choice='fixed'`"
        )


def constructor_default(algo_class: type, name: str) -> Any:
    """The default of ``name`` in the first ``__init__`` along ``algo_class``'s bases that names it (a subclass may pass
    it on through ``**kwargs``)."""
    for base in algo_class.__mro__:
        init = vars(base).get("__init__")
        parameter = inspect.signature(init).parameters.get(name) if init is not None else None
        if parameter is not None and parameter.default is not inspect.Parameter.empty:
            return parameter.default
    raise ValueError(f"`{name}`: no constructor of {algo_class.__name__} has a default for it")


def delta1_bounds(model: Any) -> tuple[float, float]:
    """
    delta1's (lambda's) start and end: ``mc_initial_prob`` and ``mc_final_prob``, or with ``lambda_horizon`` = h the
    lambda whose return contracts like an h-step return with the model's ``gamma``, for both. With n-step windows of m
    steps, lambda weighs windows: the lambda of h / m windows with discount gamma^m (h = m: lambda 0, the window's own
    m-step target). Call after :func:`check_lambda_arguments`.
    """
    if model.lambda_horizon is None:
        return model.mc_initial_prob, model.mc_final_prob
    window = model.n_steps
    lam = lambda_for_horizon(float(model.lambda_horizon) / window, model.gamma**window)
    return lam, lam


class OffOnReplayMixin:
    """The Off-On buffer's setup, loading and episode ends for an SB3 off-policy algorithm (see the module's docstring)."""

    # Attributes of the algorithm, declared for type checkers
    observation_space: spaces.Space
    replay_buffer: ReplayBuffer | None
    replay_buffer_class: type[ReplayBuffer] | None
    replay_buffer_kwargs: dict[str, Any]
    gamma: float
    n_steps: int
    target_rng: np.random.Generator
    _lambda_cache: Any
    _last_obs: Any

    def _connect_replay_buffer(self) -> None:
        """Connect a new or loaded buffer to the model (its truncation bootstrap); reject a buffer the model cannot use."""
        raise NotImplementedError

    def _setup_model_with_offon_buffer(self) -> None:
        """The algorithm's ``_setup_model`` with an Off-On buffer by default, built with the model's discounting."""
        if self.replay_buffer_class is None:
            self.replay_buffer_class = self._default_replay_buffer_class()
        # The model's gamma and n_steps are passed at each setup and not saved in replay_buffer_kwargs, so that a
        # model loaded with another gamma or n_steps builds its buffer with them (models saved before kept them there)
        user_kwargs = self.replay_buffer_kwargs
        self.replay_buffer_kwargs = {**user_kwargs, **self._buffer_discounting(self.replay_buffer_class, user_kwargs)}

        # SB3's setup calls set_random_seed(self.seed): keep the draws' generator as it is (a loaded model draws on)
        target_rng = self.target_rng
        try:
            with warnings.catch_warnings():
                if issubclass(self.replay_buffer_class, OffOnNStepReplayBuffer):  # type: ignore[arg-type]
                    # n_steps is passed on to our n-step buffer: SB3's warning that it is ignored does not apply
                    warnings.filterwarnings("ignore", message="`n_steps=.*is ignored")
                super()._setup_model()  # type: ignore[misc]
        finally:
            self.replay_buffer_kwargs = user_kwargs
        self.target_rng = target_rng

    def _default_replay_buffer_class(self) -> type[ReplayBuffer]:
        """The Off-On buffer for the observation space and ``n_steps`` (as SB3's DQN picks among its own)."""
        if isinstance(self.observation_space, spaces.Dict):
            if self.n_steps > 1:
                raise ValueError("`n_steps` > 1 is not supported for Dict observation spaces (as in SB3's DQN)")
            return OffOnDictReplayBuffer
        return OffOnNStepReplayBuffer if self.n_steps > 1 else OffOnReplayBuffer

    def _buffer_discounting(self, buffer_class: type[ReplayBuffer], buffer_kwargs: dict[str, Any]) -> dict[str, Any]:
        """The model's ``gamma`` and ``n_steps`` for an Off-On buffer (nothing for another buffer class)."""
        if not issubclass(buffer_class, OffOnBufferMixin):
            return {}
        discounting: dict[str, Any] = {"gamma": self.gamma}
        # SB3's way to ask a custom buffer for n-step returns, replay_buffer_kwargs={"n_steps": n}, still works
        if issubclass(buffer_class, OffOnNStepReplayBuffer) and (self.n_steps > 1 or "n_steps" not in buffer_kwargs):
            discounting["n_steps"] = self.n_steps
        return discounting

    def _check_buffer_discounting(self) -> None:
        # Not in _setup_model: a model saved before this check may hold its old values there, which setup replaces
        if not {"gamma", "n_steps"} & set(self.replay_buffer_kwargs):
            return  # (load() builds the model without an env: no observation space to pick a buffer class by)
        buffer_class = self.replay_buffer_class or self._default_replay_buffer_class()
        for key, value in self._buffer_discounting(buffer_class, self.replay_buffer_kwargs).items():
            if key in self.replay_buffer_kwargs and self.replay_buffer_kwargs[key] != value:
                raise ValueError(
                    f"`replay_buffer_kwargs['{key}']` ({self.replay_buffer_kwargs[key]!r}) differs from the model's "
                    f"`{key}` ({value!r}): an Off-On buffer discounts returns and TD targets with the model's"
                )

    def load_replay_buffer(self, path: Any, truncate_last_traj: bool = True) -> None:
        """
        Load a replay buffer from a pickle file, and connect an Off-On buffer to this model.

        :param path: Path to the pickled replay buffer.
        :param truncate_last_traj: As for SB3's ``HerReplayBuffer``: if ``True``, the buffer's running episodes were
            cut off (each ends as a time-limit truncation, per ``mc_truncation``); if ``False``, they go on with this
            model's current env episodes (a buffer saved by this same live model, with no env reset in between).
        """
        previous_buffer = self.replay_buffer
        super().load_replay_buffer(path, truncate_last_traj)  # type: ignore[misc]
        if isinstance(self.replay_buffer, OffOnBufferMixin):
            # Its stored returns and its n-step windows were made with its own discounting: mixing them with this
            # model's targets would train on two discounts at once
            # (n_steps: the model's, or the buffer kwargs' where the model's is 1, as _buffer_discounting builds it)
            expected = {"gamma": self.gamma, "n_steps": self.n_steps}
            if self.n_steps == 1:
                expected["n_steps"] = self.replay_buffer_kwargs.get("n_steps", 1)
            for key, value in expected.items():
                loaded = getattr(self.replay_buffer, key)
                if loaded != value:
                    self.replay_buffer = previous_buffer
                    raise ValueError(
                        f"The loaded replay buffer's `{key}` ({loaded!r}) differs from the model's ({value!r}): an Off-On "
                        "buffer's returns and n-step windows are made with the model's discounting"
                    )
        self._lambda_cache = None  # its slots were of the buffer it replaces
        self._connect_replay_buffer()
        if truncate_last_traj and isinstance(self.replay_buffer, OffOnBufferMixin):
            self.replay_buffer.end_open_episodes()

    def set_random_seed(self, seed: int | None = None) -> None:
        """
        Seed the global RNGs, the action space and the env as SB3 does, and the target draws' own generator.

        :param seed: the seed (None: leave everything as it is, as SB3 does)
        """
        super().set_random_seed(seed)  # type: ignore[misc]
        if seed is not None:
            self.target_rng = np.random.default_rng(seed)

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> Any:
        env_resets = reset_num_timesteps or self._last_obs is None
        result = super()._setup_learn(  # type: ignore[misc]
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        if env_resets and isinstance(self.replay_buffer, OffOnBufferMixin):
            # Episodes still running in the buffer were cut off by this reset
            self.replay_buffer.end_open_episodes()
            self._lambda_cache = None  # their last transitions' returns are no longer those of running episodes
        return result
