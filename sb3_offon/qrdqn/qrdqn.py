"""
sb3-contrib's QR-DQN with its quantile Huber loss computed from sorted targets (:mod:`sb3_offon.common.quantile_loss`):
the same algorithm, arguments, saved files and results to float rounding, at about four times the env steps per second
on one CPU thread when it trains every 4 steps on MinAtar (sb3-contrib's loss was most of each gradient step; the
figures: docs/qrdqn.md).
"""

import inspect
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import sb3_contrib
from sb3_contrib.qrdqn import qrdqn as sb3_contrib_qrdqn

from sb3_offon.common.non_finite import NonFiniteChecksMixin
from sb3_offon.common.offon_model import check_positive_integer, check_training_arguments
from sb3_offon.common.quantile_loss import quantile_huber_loss

_swap_lock = threading.Lock()
_trainings_in_progress = 0
_sb3_contrib_loss = sb3_contrib_qrdqn.quantile_huber_loss


@contextmanager
def _sorted_quantile_huber_loss() -> Iterator[None]:
    """
    sb3-contrib's ``QRDQN.train`` calls the loss by its module's global name: point that name at this package's loss while
    one of these models trains, so that ``train`` itself stays sb3-contrib's (nothing copied). The first training to
    start swaps it and the last to end puts the original back, so models training in threads do not undo each other.
    Any sb3-contrib QRDQN that trains meanwhile gets this loss too: the same values, sooner.
    """
    global _trainings_in_progress
    with _swap_lock:
        if _trainings_in_progress == 0:
            sb3_contrib_qrdqn.quantile_huber_loss = quantile_huber_loss
        _trainings_in_progress += 1
    try:
        yield
    finally:
        with _swap_lock:
            _trainings_in_progress -= 1
            if _trainings_in_progress == 0:
                sb3_contrib_qrdqn.quantile_huber_loss = _sb3_contrib_loss


class QRDQN(NonFiniteChecksMixin, sb3_contrib.QRDQN):
    """
    Quantile Regression Deep Q-Network (QR-DQN), sb3-contrib's, with a faster loss: every argument, method and saved
    file is sb3-contrib's ``QRDQN``'s; only the quantile Huber loss of ``train`` is computed from sorted targets, with
    its gradient in closed form (:class:`sb3_offon.common.quantile_loss.QuantileHuberLoss`). A model saved by either class
    loads with the other.

    Paper: https://arxiv.org/abs/1710.10044

    The constructor is sb3-contrib's: ``QRDQN(policy, env, ...)`` with the same arguments and defaults. Added: a
    ``buffer_size``, ``n_quantiles``, ``batch_size``, ``n_steps``, ``train_freq`` or ``target_update_interval``
    below 1, a ``gradient_steps`` below -1 or a negative ``learning_starts`` is a ``ValueError`` naming it, and a
    non-finite reward or loss stops training with an error naming the env and step
    (:mod:`sb3_offon.common.non_finite`; set the attribute ``non_finite = "skip"`` to skip steps with a non-finite
    reward instead).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        # sb3-contrib's constructor divides by batch_size (Adam's eps) before _setup_model checks the rest
        arguments = inspect.signature(sb3_contrib.QRDQN.__init__).bind(self, *args, **kwargs).arguments
        check_positive_integer("batch_size", arguments.get("batch_size", 32))
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        check_positive_integer("buffer_size", self.buffer_size)
        check_training_arguments(self)
        check_positive_integer("n_quantiles", self.policy_kwargs.get("n_quantiles", 200))
        super()._setup_model()

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        with _sorted_quantile_huber_loss():
            super().train(gradient_steps, batch_size)
        self._check_training_loss()
