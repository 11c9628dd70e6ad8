"""
OffOnDQN's coin-flip targets (``mc_mixing`` ``"sample"``, ``"convex"``, ``"max"``): the training call, which target each
sample gets, the targets themselves, Sarsa's bootstrap, and the statistics of a training call.
"""

from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.vec_env import VecNormalize
from stable_baselines3.dqn.policies import QNetwork

from sb3_offon.common.buffers import OffOnDictReplayBufferSamples, OffOnReplayBufferSamples
from sb3_offon.common.chunks import rows_of
from sb3_offon.common.prioritized_buffers import PrioritizedBufferMixin

Samples = OffOnReplayBufferSamples | OffOnDictReplayBufferSamples


class CoinFlipTargetsMixin:
    """The targets of :class:`sb3_offon.OffOnDQN` where one is drawn per sample (see its docstring)."""

    # Attributes and methods of OffOnDQN (and SB3's DQN), declared for type checkers
    replay_buffer: Any  # an Off-On buffer here (OffOnDQN.train checks it)
    policy: Any  # DQNPolicy (SB3 declares it differently in BaseAlgorithm and DQN)
    q_net: QNetwork
    q_net_target: QNetwork
    logger: Logger
    gamma: float
    max_grad_norm: float
    mc_prob: float
    qlearning_prob: float
    mc_mixing: str
    sarsa_target: str
    exploration_rate: float
    target_rng: np.random.Generator
    _n_updates: int
    _vec_normalize_env: VecNormalize | None
    _update_learning_rate: Callable[..., None]
    _steps_per_chunk: Callable[[int], int]
    _to_device: Callable[[np.ndarray], th.Tensor]
    _loss_fn: Callable[[], Callable[..., th.Tensor]]
    _bootstrap: Callable[[Any], tuple[th.Tensor, th.Tensor, th.Tensor]]
    _online_greedy_actions: Callable[[Any], th.Tensor]
    _parameter_list: Callable[[], list[th.nn.Parameter]]

    def _train_on_coin_flip_targets(self, gradient_steps: int, batch_size: int) -> None:
        """
        ``gradient_steps`` updates of the Q-network towards targets drawn per sample (see :meth:`train`): the
        minibatches are gathered and uploaded in chunks, the target network's values of a chunk come from one forward
        pass, the choice of targets is made on the host and the statistics are read from the device once.
        """
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        loss_fn = self._loss_fn()
        # All of this call's target draws at once: uniforms for the MC choice and for the Q-learning/Sarsa choice
        uniforms = self.target_rng.random((2, gradient_steps * batch_size, 1), dtype=np.float32)
        mc_drawn, sarsa_drawn = uniforms[0] < self.mc_prob, uniforms[1] >= self.qlearning_prob
        # Expected Sarsa's behaviour policy is the online network, which each step changes: its targets are per step
        targets_per_step = self.sarsa_target == "expected" and self.qlearning_prob < 1.0
        # Listed once (not by walking the policy's modules at each step, as SB3's DQN does): the same clipping
        parameters = self._parameter_list()
        # Prioritised replay: the call's minibatches are drawn with the priorities as they are at its start, and the
        # errors of its gradient steps update them once, at its end (one read from the device per call)
        prioritized = isinstance(self.replay_buffer, PrioritizedBufferMixin)
        drawn_slots, drawn_envs, errors = [], [], []
        losses, q_taken, mc_returns, bound_active = [], [], [], []
        n_mc_targets = n_sarsa_targets = 0
        steps_per_chunk = self._steps_per_chunk(batch_size)
        for first_step in range(0, gradient_steps, steps_per_chunk):
            n_steps = min(steps_per_chunk, gradient_steps - first_step)
            chunk = slice(first_step * batch_size, (first_step + n_steps) * batch_size)
            if prioritized:
                batches, slots, envs, weights = self.replay_buffer.sample_prioritized(
                    n_steps, batch_size, env=self._vec_normalize_env
                )
                drawn_slots.append(slots)
                drawn_envs.append(envs)
                weights_tensor = self._to_device(weights.reshape(-1, 1))
            else:
                batches = self.replay_buffer.sample_minibatches(n_steps, batch_size, env=self._vec_normalize_env)
            data = batches.samples
            use_mc, use_sarsa = self._target_choice(
                batches.mc_returns, batches.next_actions, mc_drawn[chunk], sarsa_drawn[chunk]
            )
            n_mc_targets += 0 if use_mc is None else int(np.count_nonzero(use_mc))
            n_sarsa_targets += 0 if use_sarsa is None else int(np.count_nonzero(use_sarsa))
            if not targets_per_step:
                with th.no_grad():
                    targets, bound = self._targets(data, use_mc, use_sarsa)
                bound_active += [] if bound is None else [bound]

            for step in range(n_steps):
                rows = slice(step * batch_size, (step + 1) * batch_size)
                if targets_per_step:
                    with th.no_grad():
                        step_targets, bound = self._targets(
                            rows_of(data, rows), rows_of(use_mc, rows), rows_of(use_sarsa, rows)
                        )
                    bound_active += [] if bound is None else [bound]
                else:
                    step_targets = targets[rows]

                current_q_values = self.q_net(rows_of(data.observations, rows))
                current_q_values = th.gather(current_q_values, dim=1, index=data.actions[rows].long())
                if prioritized:
                    # Each sample's loss weighted by its importance weight (Schaul et al. 2016)
                    loss = (loss_fn(current_q_values, step_targets, reduction="none") * weights_tensor[rows]).mean()
                    errors.append((step_targets - current_q_values).detach())
                else:
                    loss = loss_fn(current_q_values, step_targets)

                self.policy.optimizer.zero_grad()
                loss.backward()
                th.nn.utils.clip_grad_norm_(parameters, self.max_grad_norm)
                self.policy.optimizer.step()

                # Kept on the device: reading the loss back at each step, as SB3 does, would wait for the device
                losses.append(loss.detach())
                q_taken.append(current_q_values.detach())
            mc_returns.append(data.mc_returns)

        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if prioritized:
            self.replay_buffer.update_priorities(
                np.concatenate(drawn_slots), np.concatenate(drawn_envs), th.cat(errors).cpu().numpy()
            )
        self._record_target_statistics(
            th.stack(losses), th.cat(q_taken), th.cat(mc_returns), n_mc_targets, n_sarsa_targets, bound_active
        )

    def _target_choice(
        self, mc_returns: np.ndarray, next_actions: np.ndarray, mc_drawn: np.ndarray, sarsa_drawn: np.ndarray
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """
        Which target each sample gets, decided on the host from its return and next action (NumPy arrays as sampled).

        :param mc_returns: per sample, the Monte-Carlo return (NaN: unknown)
        :param next_actions: per sample, the action taken at s' (-1: unknown)
        :param mc_drawn: per sample, whether the draw picked the Monte-Carlo target (used where G is known)
        :param sarsa_drawn: per sample, whether the draw picked Sarsa over Q-learning (used where a' is known)
        :return: the masks of samples whose target is Monte-Carlo (or, with ``mc_mixing`` ``"convex"``/``"max"``, whose
            target the return enters) and Sarsa; None where that target is not drawn at all
        """
        use_mc = use_sarsa = None
        if self.mc_prob > 0.0:
            known_return = ~np.isnan(mc_returns)
            use_mc = known_return if self.mc_mixing == "convex" else known_return & mc_drawn
        if self.qlearning_prob < 1.0:
            known_action = np.ones(next_actions.shape, dtype=bool) if self.sarsa_target == "expected" else next_actions >= 0
            use_sarsa = known_action & sarsa_drawn
            if use_mc is not None and self.mc_mixing == "sample":
                use_sarsa &= ~use_mc  # a Monte-Carlo target replaces the TD target altogether
        return use_mc, use_sarsa

    def _targets(
        self, replay_data: Samples, use_mc: np.ndarray | None, use_sarsa: np.ndarray | None
    ) -> tuple[th.Tensor, th.Tensor | None]:
        """
        The regression targets of a batch of samples (one or several minibatches), from the target choice of
        :meth:`_target_choice`. Nothing is read back from the device.

        :param replay_data: the samples
        :param use_mc: the samples whose target is (or, mixed, includes) their Monte-Carlo return; None: none
        :param use_sarsa: the samples whose TD target is Sarsa's; None: none
        :return: the targets and (``mc_mixing="max"``) the mask, on the device, of samples where the return was above
            the TD target and so decided it
        """
        bound_active = None
        # For n-step replay, discount factor is gamma**n_steps (when no early termination)
        discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma
        next_q_values_all, greedy_actions, next_q_values = self._bootstrap(replay_data.next_observations)
        next_q_values = next_q_values.reshape(-1, 1)
        if use_sarsa is not None and np.count_nonzero(use_sarsa):
            next_q_values = self._sarsa_next_values(replay_data, next_q_values_all, next_q_values, greedy_actions, use_sarsa)
        # Written as in SB3's DQN: with Q-learning only, the targets are bit-identical
        target_q_values = replay_data.rewards + (1 - replay_data.dones) * discounts * next_q_values

        if use_mc is not None and np.count_nonzero(use_mc):
            mc_targets = replay_data.mc_returns
            use_mc_tensor = self._to_device(use_mc)
            if self.mc_mixing == "convex":
                mc_targets = self.mc_prob * mc_targets + (1.0 - self.mc_prob) * target_q_values
            elif self.mc_mixing == "max":
                # The return as a lower bound: it decides the target only where it is above the TD target
                bound_active = use_mc_tensor & (mc_targets > target_q_values)
                mc_targets = th.maximum(mc_targets, target_q_values)
            target_q_values = th.where(use_mc_tensor, mc_targets, target_q_values)
        return target_q_values, bound_active

    def _sarsa_next_values(
        self,
        replay_data: Samples,
        next_q_values_all: th.Tensor,
        max_next_q_values: th.Tensor,
        greedy_actions: th.Tensor,
        use_sarsa: np.ndarray,
    ) -> th.Tensor:
        """The values of the next states: Sarsa's where ``use_sarsa``, Q-learning's (``max_next_q_values``) elsewhere."""
        use_sarsa_tensor = self._to_device(use_sarsa)
        if self.sarsa_target == "expected":
            # Expectation under the behaviour policy: epsilon-greedy on the online network
            behaviour_greedy = self._online_greedy_actions(replay_data.next_observations).reshape(-1, 1)
            greedy_values = th.gather(next_q_values_all, dim=1, index=behaviour_greedy)
            expected = self.exploration_rate * next_q_values_all.mean(dim=1, keepdim=True)
            expected = expected + (1.0 - self.exploration_rate) * greedy_values
            return th.where(use_sarsa_tensor, expected, max_next_q_values)
        # One gather, on the device: at the recorded next action a' for Sarsa, at the bootstrap action elsewhere (the
        # target network's greedy action, which reads back exactly the max, or the online network's with double Q;
        # a' is -1 there where unknown, and not used)
        bootstrap_actions = th.where(use_sarsa_tensor, replay_data.next_actions, greedy_actions.reshape(-1, 1))
        return th.gather(next_q_values_all, dim=1, index=bootstrap_actions)

    def _record_target_statistics(
        self,
        losses: th.Tensor,
        q_taken: th.Tensor,
        mc_returns: th.Tensor,
        n_mc_targets: int,
        n_sarsa_targets: int,
        bound_active: list[th.Tensor] | None = None,
    ) -> None:
        """
        Log a training call's statistics, with one read from the device.

        :param losses: the loss of each gradient step
        :param q_taken: Q(s, a) of every sample, as the online network gave it at its step
        :param mc_returns: every sample's return (NaN: unknown)
        :param n_mc_targets: the number of samples whose target is (or includes) the return
        :param n_sarsa_targets: the number of samples whose TD target is Sarsa's
        :param bound_active: ``mc_mixing="max"``: masks of the samples whose target the return decided
        """
        # NaN where G is unknown: nansum leaves those samples out of the sum, and the count of known ones divides it
        gaps = q_taken - mc_returns
        n_bound_active = sum(mask.sum() for mask in bound_active) if bound_active else th.zeros((), device=losses.device)
        loss, gap_sum, n_known, n_bound = th.stack(
            [losses.mean(), th.nansum(gaps), (gaps == gaps).sum().to(losses.dtype), th.as_tensor(n_bound_active).to(losses)]
        ).tolist()
        n_samples = len(mc_returns)
        self.logger.record("train/loss", loss)
        self.logger.record("train/mc_target_fraction", n_mc_targets / n_samples)
        self.logger.record("train/sarsa_target_fraction", n_sarsa_targets / n_samples)
        if self.mc_mixing == "max":
            self.logger.record("train/mc_bound_active_fraction", n_bound / n_samples)
        if n_known > 0:
            self.logger.record("train/q_mc_gap", gap_sum / n_known)
