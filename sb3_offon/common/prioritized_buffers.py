"""
Prioritised experience replay (Schaul, Quan, Antonoglou & Silver, "Prioritized Experience Replay", ICLR 2016) for the
Off-On buffers: each stored transition (a slot of one env column) has a priority p, and is sampled with probability
P(i) = p_i^alpha / sum_k p_k^alpha from a sum tree (:class:`sb3_offon.common.sum_tree.SumTree`, a whole batch per
call), its loss weighted by the importance-sampling weight w_i = (N P(i))^-beta / max_k (N P(k))^-beta, N the number of
stored transitions: the maximum is over the whole buffer (the transition with the smallest priority), as in the paper,
so that a transition's weight is a function of its probability alone, whatever else its minibatch holds.

- A new transition enters at the highest priority seen so far (1 before any update), so that it is replayed at least
  once soon; overwriting a slot gives the new transition that priority too.
- Priorities come from the training: p = |error| + epsilon after each training call, the error being the TD error for
  OffOnDQN (target minus Q) and the per-sample quantile Huber loss for OffOnQRDQN (as Rainbow uses its per-sample KL).
- beta is annealed from ``beta`` to ``final_beta`` (1, the paper's) over training: the algorithm sets
  :attr:`beta` at each training call from its progress.
- ``alpha=0`` samples uniformly (every p^0 = 1) with unit weights.
- The draws come from the buffer's own generator, seeded from NumPy's global one when the buffer is built (SB3 seeds
  that first), so that a run seeded the SB3 way is reproducible; the generator, the tree and the highest priority are
  saved with the buffer (``save_replay_buffer``, the checkpoints of :mod:`sb3_offon.resume`).

``optimize_memory_usage`` is not supported with prioritisation: there the newest slot holds no next observation yet,
and the tree would have to keep that slot's priority at 0 and restore it one step later.
"""

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecNormalize

from sb3_offon.common.buffers import (
    OffOnBufferMixin,
    OffOnDictReplayBuffer,
    OffOnDictReplayBufferSamples,
    OffOnMinibatches,
    OffOnNStepReplayBuffer,
    OffOnReplayBuffer,
    OffOnReplayBufferSamples,
    reward_scale,
)
from sb3_offon.common.non_finite import NonFiniteError
from sb3_offon.common.sum_tree import SumTree


class PrioritizedBufferMixin(OffOnBufferMixin):
    """
    Priorities, their sum tree and importance weights on top of an Off-On buffer (see the module's docstring).

    :param alpha: how much the priorities count (0: uniform sampling)
    :param beta: the importance-sampling exponent at the start of training
    :param final_beta: the importance-sampling exponent at the end of training (beta goes linearly to it)
    :param epsilon: added to each absolute error, so that no transition's priority is 0
    """

    alpha: float
    beta: float
    initial_beta: float
    final_beta: float
    epsilon: float
    max_priority: float
    _tree: SumTree

    def _init_prioritized(self, alpha: float, beta: float, final_beta: float, epsilon: float) -> None:
        for name, value, low, high in (
            ("alpha", alpha, 0.0, np.inf),
            ("beta", beta, 0.0, 1.0),
            ("final_beta", final_beta, 0.0, 1.0),
            ("epsilon", epsilon, 0.0, np.inf),
        ):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
                raise ValueError(f"`{name}` must be a number in [{low}, {high}], got {value!r}")
        if epsilon <= 0:
            raise ValueError(f"`epsilon` must be positive, so that no priority is 0, got {epsilon!r}")
        if self.optimize_memory_usage:
            raise ValueError("`optimize_memory_usage` is not supported with prioritised replay")
        self.alpha, self.epsilon = float(alpha), float(epsilon)
        self.initial_beta, self.beta, self.final_beta = float(beta), float(beta), float(final_beta)
        self._tree = SumTree(self.buffer_size * self.n_envs)
        self.max_priority = 1.0
        # Leaf values set since the tree was last brought up to date: applied in one update when it is read, so that
        # adding a transition (each env step) and a training call's new priorities cost no tree update of their own
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []
        # The draws' generator, seeded from NumPy's global one (which SB3 seeds before it builds the buffer), saved with
        # the buffer: a run seeded the SB3 way draws the same samples, and a reloaded buffer draws on
        self.rng = np.random.default_rng(np.random.randint(2**31))

    @property
    def tree(self) -> SumTree:
        """The sum tree of the priorities (p^alpha per transition), up to date."""
        if self._pending:
            leaves, values = (np.concatenate(parts) for parts in zip(*self._pending, strict=True))
            self._pending = []
            # In the order they were set (the last value of a leaf wins); made here, so no check is needed
            self._tree.update(leaves, values, check=False)
        return self._tree

    def reset(self) -> None:
        super().reset()
        if hasattr(self, "_tree"):
            self._tree = SumTree(self.buffer_size * self.n_envs)
            self._pending = []
            self.max_priority = 1.0

    def __getstate__(self) -> dict[str, Any]:
        self.tree  # noqa: B018  (brings the tree up to date, so that what is saved is)
        return super().__getstate__()

    def anneal_beta(self, progress_remaining: float) -> None:
        """Set :attr:`beta` from the training's progress (1 at the start, 0 at the end): linear to ``final_beta``."""
        self.beta = self.initial_beta + (1.0 - progress_remaining) * (self.final_beta - self.initial_beta)

    def leaves(self, slots: np.ndarray, envs: np.ndarray) -> np.ndarray:
        """The tree's leaf of each transition (slot, env column)."""
        return np.asarray(slots, dtype=np.int64) * self.n_envs + np.asarray(envs, dtype=np.int64)

    def add(self, *args: Any, **kwargs: Any) -> None:
        slot = self.pos
        super().add(*args, **kwargs)
        # The new transitions (one per env column) at the highest priority so far
        new = self.leaves(np.full(self.n_envs, slot), np.arange(self.n_envs))
        self._pending.append((new, np.full(self.n_envs, self._leaf_value(self.max_priority))))

    def _leaf_value(self, priority: float | np.ndarray) -> Any:
        return np.power(priority, self.alpha)

    def update_priorities(self, slots: np.ndarray, envs: np.ndarray, errors: np.ndarray) -> np.ndarray:
        """
        Set the priorities of the transitions (slot, env column) from their errors: p = |error| + epsilon.

        :param slots: the transitions' slots
        :param envs: their env columns
        :param errors: their errors (TD errors, or per-sample losses), one per transition
        :return: the values set in the tree, p^alpha (float64), one per transition: what another tree over the same
            transitions (the lambda-return cache's) sets, so that the two hold the same numbers
        """
        priorities = np.abs(np.asarray(errors, dtype=np.float64).reshape(-1)) + self.epsilon
        if not np.all(np.isfinite(priorities)):
            raise NonFiniteError(
                "Non-finite training error (NaN or inf) for a priority: the values diverged; lower the learning rate or "
                "scale the rewards"
            )
        leaves = self.leaves(slots, envs)
        if len(leaves) != len(priorities) or (len(leaves) and (leaves.min() < 0 or leaves.max() >= len(self._tree))):
            raise ValueError("prioritised replay: one error per stored transition (slot < buffer_size, env < n_envs)")
        self.max_priority = max(self.max_priority, float(priorities.max(initial=0.0)))
        values = self._leaf_value(priorities)
        self._pending.append((leaves, values))
        return values

    def n_transitions(self) -> int:
        """How many transitions are stored (all env columns)."""
        return (self.buffer_size if self.full else self.pos) * self.n_envs

    def draw(self, n_samples: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        ``n_samples`` stored transitions in proportion to p^alpha (stratified: one per equal slice of the total), and
        their importance weights.

        :return: slots, env columns, weights (float32, at most 1)
        """
        leaves = self.tree.sample(n_samples, self.rng)
        slots, envs = np.divmod(leaves, self.n_envs)
        return slots, envs, self.weights(self.tree.probabilities(leaves))

    def weights(self, probabilities: np.ndarray) -> np.ndarray:
        """(N P(i))^-beta, divided by its largest value over the stored transitions (that of the smallest priority)."""
        n_stored = self.n_transitions()
        tree = self.tree
        smallest = tree.min / tree.total
        return ((probabilities / smallest) ** -self.beta).astype(np.float32) if n_stored else np.ones(0, np.float32)

    def sample_prioritized(
        self, n_batches: int, batch_size: int, env: VecNormalize | None = None
    ) -> tuple[OffOnMinibatches, np.ndarray, np.ndarray, np.ndarray]:
        """
        ``n_batches`` minibatches of ``batch_size`` transitions drawn by priority, made into Off-On samples (as
        ``sample_minibatches`` makes them), with their slots, env columns and importance weights.

        The samples are built from the same stored fields as SB3's: the n-step window of each transition
        (:meth:`lambda_inputs`, SB3's ``NStepReplayBuffer`` windows), ``dones`` as termination only (time-limit
        truncations bootstrap), the rewards and observations normalised as ``sample()`` normalises them.
        """
        slots, envs, weights = self.draw(n_batches * batch_size)
        observations, actions = self.observations_and_actions(slots, envs, env)
        inputs = self.lambda_inputs(slots, envs, self.gamma, env)
        mc_returns = self.mc_returns[slots, envs].reshape(-1, 1)
        if env is not None:
            mc_returns = mc_returns / reward_scale(env)
        next_actions = self._sarsa_next_actions(slots, envs).reshape(-1, 1)
        columns: dict[str, Any] = dict(
            observations=observations,
            actions=actions,
            next_observations=inputs["next_observations"].array(),  # a minibatch's: uploaded with the other columns
            dones=inputs["terminated"].astype(np.float32).reshape(-1, 1),
            rewards=inputs["rewards"].astype(np.float32).reshape(-1, 1),
            # n-step windows discount by gamma^k; one-step samples use the model's gamma, as SB3's do (discounts None)
            discounts=inputs["discounts"].astype(np.float32).reshape(-1, 1) if self.n_steps > 1 else None,
        )
        sample_class = OffOnDictReplayBufferSamples if isinstance(observations, dict) else OffOnReplayBufferSamples
        uploaded: dict[str, Any] = {
            name: None if value is None else _upload(value, self.to_torch) for name, value in columns.items()
        }
        samples = sample_class(
            **uploaded, next_actions=self.to_torch(next_actions), mc_returns=self.to_torch(mc_returns.astype(np.float32))
        )
        return OffOnMinibatches(samples, next_actions, mc_returns), slots, envs, weights


def _upload(value: Any, to_torch: Any) -> Any:
    if isinstance(value, dict):
        return {key: to_torch(item) for key, item in value.items()}
    return to_torch(value)


class PrioritizedOffOnReplayBuffer(PrioritizedBufferMixin, OffOnReplayBuffer):
    """
    :class:`sb3_offon.OffOnReplayBuffer` with prioritised replay (see :mod:`sb3_offon.common.prioritized_buffers`).

    :param buffer_size: Max number of element in the buffer
    :param observation_space: Observation space
    :param action_space: Action space (Discrete)
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported with prioritisation
    :param handle_timeout_termination: Handle timeout termination (due to timelimit) separately
    :param gamma: Discount factor of the Monte-Carlo returns
    :param alpha: how much the priorities count (0: uniform); Rainbow's 0.5
    :param beta: the importance-sampling exponent at the start of training; Rainbow's 0.4
    :param final_beta: the exponent at the end of training, reached linearly
    :param epsilon: added to each absolute error
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        gamma: float = 0.99,
        alpha: float = 0.5,
        beta: float = 0.4,
        final_beta: float = 1.0,
        epsilon: float = 1e-6,
    ):
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device,
            n_envs,
            optimize_memory_usage,
            handle_timeout_termination,
            gamma,
        )
        self._init_prioritized(alpha, beta, final_beta, epsilon)


class PrioritizedOffOnNStepReplayBuffer(PrioritizedBufferMixin, OffOnNStepReplayBuffer):
    """
    :class:`sb3_offon.OffOnNStepReplayBuffer` with prioritised replay (see :mod:`sb3_offon.common.prioritized_buffers`).

    :param buffer_size: Max number of element in the buffer
    :param observation_space: Observation space
    :param action_space: Action space (Discrete)
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported
    :param handle_timeout_termination: Handle timeout termination (due to timelimit) separately
    :param n_steps: Number of steps to accumulate rewards for n-step returns
    :param gamma: Discount factor of the n-step and Monte-Carlo returns
    :param alpha: how much the priorities count (0: uniform); Rainbow's 0.5
    :param beta: the importance-sampling exponent at the start of training; Rainbow's 0.4
    :param final_beta: the exponent at the end of training, reached linearly
    :param epsilon: added to each absolute error
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        n_steps: int = 3,
        gamma: float = 0.99,
        alpha: float = 0.5,
        beta: float = 0.4,
        final_beta: float = 1.0,
        epsilon: float = 1e-6,
    ):
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device,
            n_envs,
            optimize_memory_usage,
            handle_timeout_termination,
            n_steps=n_steps,
            gamma=gamma,
        )
        self._init_prioritized(alpha, beta, final_beta, epsilon)


class PrioritizedOffOnDictReplayBuffer(PrioritizedBufferMixin, OffOnDictReplayBuffer):
    """
    :class:`sb3_offon.OffOnDictReplayBuffer` with prioritised replay (see :mod:`sb3_offon.common.prioritized_buffers`).

    :param buffer_size: Max number of element in the buffer
    :param observation_space: Observation space (Dict)
    :param action_space: Action space (Discrete)
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported
    :param handle_timeout_termination: Handle timeout termination (due to timelimit) separately
    :param gamma: Discount factor of the Monte-Carlo returns
    :param alpha: how much the priorities count (0: uniform); Rainbow's 0.5
    :param beta: the importance-sampling exponent at the start of training; Rainbow's 0.4
    :param final_beta: the exponent at the end of training, reached linearly
    :param epsilon: added to each absolute error
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Dict,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        gamma: float = 0.99,
        alpha: float = 0.5,
        beta: float = 0.4,
        final_beta: float = 1.0,
        epsilon: float = 1e-6,
    ):
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device,
            n_envs,
            optimize_memory_usage,
            handle_timeout_termination,
            gamma,
        )
        self._init_prioritized(alpha, beta, final_beta, epsilon)


# By name, for the command line (sb3_offon.zoo makes them known to the zoo's evaluation of `replay_buffer_class`)
PRIORITIZED_BUFFERS = (PrioritizedOffOnReplayBuffer, PrioritizedOffOnNStepReplayBuffer, PrioritizedOffOnDictReplayBuffer)
