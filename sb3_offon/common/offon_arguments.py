"""
The Off-On arguments that :class:`sb3_offon.OffOnDQN` and :class:`sb3_offon.OffOnQRDQN` share, handled once, as SB3's
``OffPolicyAlgorithm`` handles what its algorithms share: :class:`OffOnArgumentsMixin` sets them as attributes, checks
them (at each ``_setup_model``, which ``load()`` runs too), builds the delta1 (lambda) and delta2 schedules from them,
moves the schedules at each training call and leaves the schedules and the lambda-return cache out of saved files.

An argument added to :data:`OFFON_PARAMETERS` (and to :meth:`OffOnArgumentsMixin._check_offon_arguments`) is set,
checked and saved the same way by both classes; each still states it in its own signature and docstring, SB3 style.
"""

from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.common.utils import LinearSchedule

from sb3_offon.common.non_finite import NON_FINITE_OPTIONS
from sb3_offon.common.offon_model import (
    OffOnReplayMixin,
    check_lambda_arguments,
    check_option,
    check_training_arguments,
    delta1_bounds,
)
from sb3_offon.common.prioritized_buffers import PrioritizedBufferMixin

# The constructor arguments OffOnDQN adds to DQN's, and OffOnQRDQN (with its own ``lambda_form`` and ``lambda_cache``)
# to QRDQN's, besides ``non_finite``
OFFON_PARAMETERS = (
    "mc_initial_prob",
    "mc_final_prob",
    "mc_fraction",
    "qlearning_initial_prob",
    "qlearning_final_prob",
    "qlearning_fraction",
    "mc_mixing",
    "sarsa_target",
    "mc_truncation",
    "loss",
    "lambda_block_size",
    "lambda_refresh_interval",
    "lambda_choice",
    "lambda_horizon",
    "double_q",
)


def constructor_arguments(local_variables: dict[str, Any]) -> dict[str, Any]:
    """
    A constructor's arguments, by name, from its ``locals()`` taken before it assigns anything: less ``self`` and the
    ``__class__`` cell that ``super()`` adds.
    """
    return {name: value for name, value in local_variables.items() if name not in ("self", "__class__")}


class OffOnArgumentsMixin(OffOnReplayMixin):
    """
    The Off-On arguments' handling for an SB3 off-policy algorithm with an Off-On buffer (see the module's docstring).
    It goes right before the algorithm class (SB3's ``DQN``, the package's ``QRDQN``) in the bases, in place of
    :class:`sb3_offon.common.offon_model.OffOnReplayMixin`, which it extends.

    A subclass states its arguments in its own ``__init__`` and passes them all on by keyword:
    ``super().__init__(**constructor_arguments(locals()))``; those named in ``offon_parameters`` become attributes, the
    others go to the algorithm's constructor. It extends ``_check_offon_arguments`` with the checks of its own
    arguments, and implements ``_connect_replay_buffer``.
    """

    # The constructor arguments set as attributes rather than passed on to the algorithm's constructor
    offon_parameters: ClassVar[tuple[str, ...]] = (*OFFON_PARAMETERS, "non_finite")

    mc_initial_prob: float
    mc_final_prob: float
    mc_fraction: float
    qlearning_initial_prob: float
    qlearning_final_prob: float
    qlearning_fraction: float
    mc_mixing: str
    sarsa_target: str
    mc_truncation: str
    loss: str
    lambda_block_size: int
    lambda_refresh_interval: int | None
    lambda_choice: str
    lambda_horizon: float | None
    double_q: bool
    non_finite: str
    # delta1 (lambda) and delta2: their schedules (rebuilt by _setup_model, never saved) and current values
    mc_schedule: Schedule
    qlearning_schedule: Schedule
    mc_prob: float
    qlearning_prob: float
    # Attributes of the algorithm, declared for type checkers
    logger: Logger
    _current_progress_remaining: float

    def __init__(self, *, seed: int | None = None, _init_setup_model: bool = True, **arguments: Any) -> None:
        offon_arguments = {name: arguments.pop(name) for name in list(arguments) if name in self.offon_parameters}
        missing = [name for name in self.offon_parameters if name not in offon_arguments]
        if missing:
            raise TypeError(f"{type(self).__name__}: Off-On arguments not passed on to OffOnArgumentsMixin: {missing}")
        super().__init__(seed=seed, _init_setup_model=False, **arguments)  # type: ignore[call-arg]
        # Work on a copy, so that the caller's dict is left as it was
        self.replay_buffer_kwargs = dict(self.replay_buffer_kwargs)
        for name, value in offon_arguments.items():
            setattr(self, name, value)
        # The Off-On arguments are checked by _setup_model (which load() also runs); the buffer's discounting here, on
        # the caller's arguments only
        self._check_buffer_discounting()
        # The target draws (sampled horizons) have a generator of their own: they never move the global RNGs that SB3
        # uses for exploration and sampling, and its state is saved with the model, so a resumed run draws on.
        self.target_rng = np.random.default_rng(seed)
        # Current delta1 and delta2, updated at each training call (like ``exploration_rate``)
        self.mc_prob = self.mc_initial_prob
        self.qlearning_prob = self.qlearning_initial_prob
        if _init_setup_model:
            self._setup_model()

    def _check_offon_arguments(self) -> None:
        """
        Check the arguments both classes share: SB3's off-policy ones that SB3 leaves unchecked, the delta1 and delta2
        schedules, ``mc_truncation``, ``double_q``, the lambda settings and ``non_finite``. A class extends it with its
        own arguments. Run by ``_setup_model`` rather than ``__init__``: load()'s kwargs and custom_objects reach the
        model without ``__init__``.

        :raises ValueError: naming the first bad parameter
        """
        check_training_arguments(self)  # before the buffer is built from them (QRDQN's _setup_model checks them again)
        check_lambda_arguments(self)
        check_option("non_finite", self.non_finite, NON_FINITE_OPTIONS)

    def _setup_model(self) -> None:
        self._check_offon_arguments()
        self._setup_model_with_offon_buffer()
        self.mc_schedule = LinearSchedule(*delta1_bounds(self), self.mc_fraction)
        self.mc_prob = self.mc_schedule(self._current_progress_remaining)  # lambda_horizon's lambda before any training
        self.qlearning_schedule = LinearSchedule(
            self.qlearning_initial_prob, self.qlearning_final_prob, self.qlearning_fraction
        )
        self._connect_replay_buffer()
        # Never pickled (see _excluded_save_params): a loaded model computes its lambda-returns afresh
        self._lambda_cache = None

    def _update_offon_schedules(self) -> None:
        """At each training call: delta1 and delta2 at the current progress, logged, and a prioritised buffer's beta."""
        self.mc_prob = self.mc_schedule(self._current_progress_remaining)
        self.qlearning_prob = self.qlearning_schedule(self._current_progress_remaining)
        self.logger.record("train/mc_prob", self.mc_prob)
        self.logger.record("train/qlearning_prob", self.qlearning_prob)
        if isinstance(self.replay_buffer, PrioritizedBufferMixin):
            self.replay_buffer.anneal_beta(self._current_progress_remaining)
            self.logger.record("train/per_beta", self.replay_buffer.beta)

    def _excluded_save_params(self) -> list[str]:
        # The schedules are rebuilt from their parameters in _setup_model
        return [*super()._excluded_save_params(), "mc_schedule", "qlearning_schedule", "_lambda_cache"]  # type: ignore[misc]
