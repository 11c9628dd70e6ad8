"""
No silent NaN: a non-finite reward or training loss stops a run with an error naming where it happened, before it
reaches a saved model.

One NaN reward poisons a Q-learner for good: the targets built from it are NaN, the gradient step spreads NaN into every
weight, and from then on every Q-value, action and evaluation is meaningless, while SB3's loop goes on and saves the
model. A non-finite reward is checked where a transition is about to be stored (:class:`NonFiniteChecksMixin`, in
OffOnDQN, OffOnQRDQN and the package's QR-DQN; :class:`NonFiniteCheck`, a callback, for any other algorithm). A
non-finite loss with finite rewards (diverging values, returns that overflow float32) is checked once per training
call, from the loss the call logs (no extra read-back from the device).

What happens is the model's ``non_finite``:

- ``"raise"`` (the default): a :class:`NonFiniteError` (a ``ValueError``) naming the env index, the step and the value;
  nothing of that step is stored;
- ``"skip"`` (a reward only): a warning, and the vectorised step's transitions are not stored; every env's running
  episode is cut there as a time-limit truncation (its returns bootstrapped from its last stored next observation,
  as when a run resumes), so that no return, n-step window or lambda-return runs across the missing step. A non-finite
  loss is never skipped: its gradient steps are already in the weights.
"""

import warnings
from typing import Any

import numpy as np
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback

from sb3_offon.common.buffers import OffOnBufferMixin
from sb3_offon.resume import cut_running_episodes

NON_FINITE_OPTIONS = ("raise", "skip")


class NonFiniteError(ValueError):
    """A non-finite reward or loss met in training (see :mod:`sb3_offon.common.non_finite`)."""


def non_finite_rewards(rewards: np.ndarray, num_timesteps: int) -> str | None:
    """
    What is wrong with a vectorised step's rewards, in a line (None when every reward is finite).

    :param rewards: the step's rewards, one per env
    :param num_timesteps: the run's step count after this step (over all envs, as SB3 counts)
    :return: e.g. "reward nan from env 0 at step 300", or None
    """
    rewards = np.asarray(rewards, dtype=np.float64).reshape(-1)
    bad = np.flatnonzero(~np.isfinite(rewards))
    if len(bad) == 0:
        return None
    which = ", ".join(f"reward {rewards[env]} from env {env}" for env in bad)
    return f"{which} at step {num_timesteps}"


def non_finite_loss(logger: Any, num_timesteps: int) -> str | None:
    """
    What is wrong with the loss the latest training call logged (``train/loss``), in a line (None when it is finite or
    not logged).

    :param logger: the model's logger
    :param num_timesteps: the run's step count
    """
    loss = getattr(logger, "name_to_value", {}).get("train/loss")
    if loss is None or np.isfinite(loss):
        return None
    return (
        f"training loss {loss} at step {num_timesteps} (the rewards so far were finite: the values diverged, or returns "
        "overflowed float32); lower the learning rate or scale the rewards"
    )


def cut_running_episodes_at_skip(replay_buffer: ReplayBuffer) -> None:
    """
    End every env's running episode in ``replay_buffer`` as a time-limit truncation at its last stored transition, the
    step after it being skipped: an Off-On buffer closes the returns (:meth:`OffOnBufferMixin.end_open_episodes`), SB3's
    buffers get the last transition marked done and timed out (:func:`sb3_offon.resume.cut_running_episodes`).
    """
    if isinstance(replay_buffer, OffOnBufferMixin):
        replay_buffer.end_open_episodes()
        return
    cut_running_episodes(replay_buffer)


class NonFiniteChecksMixin:
    """
    Checks of rewards and losses for an off-policy algorithm (before the algorithm class in its bases; ``non_finite``
    set by its constructor, else this class's default). The algorithm's ``train`` calls :meth:`_check_training_loss`
    after logging its loss.
    """

    non_finite: str = "raise"
    num_timesteps: int
    logger: Any

    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: Any,
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        problem = non_finite_rewards(reward, self.num_timesteps)
        if problem is None:
            super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)  # type: ignore[misc]
            return
        if getattr(self, "non_finite", "raise") != "skip":
            raise NonFiniteError(
                f"Non-finite {problem}: nothing of this step was stored or trained on (non_finite='skip' skips such "
                "steps with a warning)"
            )
        warnings.warn(
            f"Non-finite {problem}: the step's transitions skipped, the running episodes cut there as truncations",
            stacklevel=2,
        )
        cut_running_episodes_at_skip(replay_buffer)
        if hasattr(self, "_lambda_cache"):
            setattr(self, "_lambda_cache", None)  # noqa: B010 (the cut changed the last transitions' returns)
        # What SB3's _store_transition does after storing: the next transition starts from the new observations
        self._last_obs = new_obs
        vec_normalize_env = getattr(self, "_vec_normalize_env", None)
        if vec_normalize_env is not None:
            self._last_original_obs = vec_normalize_env.get_original_obs()

    def _check_training_loss(self) -> None:
        """:raises NonFiniteError: if the loss the latest training call logged is not finite."""
        problem = non_finite_loss(self.logger, self.num_timesteps)
        if problem is not None:
            raise NonFiniteError(f"Non-finite {problem}")


class NonFiniteCheck(BaseCallback):
    """
    The checks of :class:`NonFiniteChecksMixin` as a callback, for an algorithm without them (SB3's DQN, the zoo's
    others): a non-finite reward raises at the step it is returned, before the algorithm stores it (SB3 calls
    ``on_step`` between ``env.step`` and storing), and a non-finite logged ``train/loss`` at the start of the next
    rollout, before the callbacks after this one (checkpoints) run. It comes first in a callback list.

    :param verbose: verbosity level (unused)
    """

    def _on_step(self) -> bool:
        problem = non_finite_rewards(self.locals["rewards"], self.num_timesteps)
        if problem is not None:
            raise NonFiniteError(f"Non-finite {problem}: nothing of this step was stored or trained on")
        return True

    def _on_rollout_start(self) -> None:
        problem = non_finite_loss(self.logger, self.num_timesteps)
        if problem is not None:
            raise NonFiniteError(f"Non-finite {problem}")
