"""
OffOnDQN's own part of the training on cached lambda-returns (:class:`LambdaTrainingMixin`): the target network's pass
over the next observations and the loss of a step. When to refresh, how many returns to compute and which to train on
is shared with OffOnQRDQN (:mod:`sb3_offon.common.lambda_refresh`); the returns themselves are computed in
:mod:`sb3_offon.common.lambda_returns`.
"""

from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.dqn.policies import QNetwork

from sb3_offon.common.buffers import OffOnBufferMixin
from sb3_offon.common.lambda_refresh import LambdaRefreshMixin
from sb3_offon.common.lambda_returns import LambdaReturnCache, compute_lambda_returns


class LambdaTrainingMixin(LambdaRefreshMixin):
    """
    The lambda-return training of :class:`sb3_offon.OffOnDQN`, kept apart from its coin-flip targets (see
    ``mc_mixing="lambda"`` in OffOnDQN's docstring for what is computed, how often, and at what cost): its returns'
    computation, the target network's pass behind it, and its step loss in the shared loop
    (:meth:`LambdaRefreshMixin._train_on_lambda_cache`).
    """

    # Attributes and methods of OffOnDQN (and SB3's DQN), declared for type checkers (the rest: LambdaRefreshMixin)
    q_net: QNetwork
    q_net_target: QNetwork
    gamma: float
    mc_prob: float
    qlearning_prob: float
    mc_truncation: str
    lambda_block_size: int
    lambda_choice: str
    _to_device: Callable[[np.ndarray], th.Tensor]
    _loss_fn: Callable[[], Callable[..., th.Tensor]]
    _bootstrap: Callable[[Any], tuple[th.Tensor, th.Tensor, th.Tensor]]

    def _lambda_chunk_tensors(
        self, actions: np.ndarray, returns: np.ndarray, weights: np.ndarray | None
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        """A chunk's actions and returns as columns (one Q-value per sample), and its importance weights likewise."""
        weights_tensor = None if weights is None else self._to_device(weights.reshape(-1, 1))
        return self._to_device(actions).long(), self._to_device(returns.reshape(-1, 1)), weights_tensor

    def _lambda_step_loss(
        self, observations: Any, actions: th.Tensor, targets: th.Tensor, weights: th.Tensor | None
    ) -> tuple[th.Tensor, th.Tensor | None]:
        """The Huber (or squared) loss of the taken actions' Q-values against the lambda-returns; the TD errors."""
        current_q_values = th.gather(self.q_net(observations), dim=1, index=actions)
        loss_fn = self._loss_fn()
        if weights is None:
            return loss_fn(current_q_values, targets), None
        loss = (loss_fn(current_q_values, targets, reduction="none") * weights).mean()
        return loss, (targets - current_q_values).detach()

    def _compute_lambda_cache(self, n_wanted: int, key: int) -> LambdaReturnCache:
        """The lambda-returns of about ``n_wanted`` stored transitions, with the target network of refresh ``key``."""
        assert isinstance(self.replay_buffer, OffOnBufferMixin)
        return compute_lambda_returns(
            self.replay_buffer,
            self._target_values_and_actions,
            n_wanted=n_wanted,
            block_size=self.lambda_block_size,
            gamma=self.gamma,
            lam=self.mc_prob,
            qlearning_prob=self.qlearning_prob,
            cut_is_terminal=self.mc_truncation == "terminal",
            key=key,
            env=self._vec_normalize_env,
            choice=self.lambda_choice,
        )

    def _target_values_and_actions(self, observations: np.ndarray | dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """
        V(s) and the greedy action for a batch of (normalised) observations in the buffer's layout, in chunks of
        :meth:`_lambda_forward_rows` rows, read back to the host once: max_a Q_target(s, a) and its argmax, or, with
        ``double_q``, Q_target(s, a*) and a* = argmax_a Q(s, a) of the online network (its pass on the same chunk).
        """
        outputs = self._forward_in_chunks(observations, lambda obs: self._bootstrap(obs)[2:0:-1])
        if not outputs:
            return np.zeros(0, dtype=np.float32), np.zeros(0, dtype=np.int64)
        values, actions = outputs
        # One read-back for both (an action index is exact in float32 up to 2**24 actions)
        both = th.stack([values, actions.to(values.dtype)]).cpu().numpy()
        return both[0], both[1].astype(np.int64)
