"""
Training on cached lambda-returns: when to refresh them, how many to compute, which to train on, and the gradient steps
on them (:class:`LambdaRefreshMixin`), what OffOnDQN's ``mc_mixing="lambda"`` and OffOnQRDQN share. Each algorithm's
own part (the target network's pass over the next observations, the loss of a step) is in its folder
(:mod:`sb3_offon.offon_dqn.lambda_training`, :mod:`sb3_offon.offon_qrdqn.offon_qrdqn`); the returns themselves are
computed in :mod:`sb3_offon.common.lambda_returns`.
"""

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.type_aliases import TrainFrequencyUnit
from stable_baselines3.common.utils import obs_as_tensor
from stable_baselines3.common.vec_env import VecNormalize

from sb3_offon.common.buffers import OffOnBufferMixin
from sb3_offon.common.chunks import rows_of
from sb3_offon.common.lambda_returns import LambdaReturnCache
from sb3_offon.common.prioritized_buffers import PrioritizedBufferMixin
from sb3_offon.common.sum_tree import SumTree

# The most next observations the refresh runs through the target network at once, in rows and in bytes of float32
# observations (see _lambda_forward_rows)
LAMBDA_FORWARD_ROWS = 1024
LAMBDA_FORWARD_BYTES = 8 * 2**20


class LambdaRefreshMixin:
    """
    When an algorithm that trains on cached lambda-returns refreshes them, how many it computes, and which cached
    entries each training call draws: what :class:`sb3_offon.OffOnDQN` (``mc_mixing="lambda"``) and
    :class:`sb3_offon.OffOnQRDQN` share. A subclass computes a cache in :meth:`_compute_lambda_cache`.
    """

    # Attributes and methods of the algorithm (SB3's DQN or sb3-contrib's QR-DQN), declared for type checkers
    replay_buffer: ReplayBuffer | None
    batch_size: int
    gradient_steps: int
    train_freq: Any  # a TrainFreq once the model is set up
    n_envs: int
    target_update_interval: int
    num_timesteps: int
    lambda_refresh_interval: int | None
    device: th.device
    policy: Any
    logger: Logger
    max_grad_norm: Any  # float for DQN, float | None for QR-DQN
    _n_calls: int
    _n_updates: int
    _vec_normalize_env: VecNormalize | None
    _lambda_cache: LambdaReturnCache | None
    _observation_bytes: Callable[[], int]
    _update_learning_rate: Callable[..., None]
    _steps_per_chunk: Callable[[int], int]
    _parameter_list: Callable[[], list[th.nn.Parameter]]

    def _lambda_refresh_key(self) -> int:
        """
        Changes exactly when the cached lambda-returns are due: at each target network update (SB3's ``_on_step``
        updates it every ``target_update_interval // n_envs`` calls), or every ``lambda_refresh_interval`` env steps.
        """
        if self.lambda_refresh_interval is not None:
            return self.num_timesteps // self.lambda_refresh_interval
        return self._n_calls // max(self.target_update_interval // self.n_envs, 1)

    def _refreshed_lambda_cache(self, n_samples: int) -> LambdaReturnCache:
        """
        The cached lambda-returns, computed afresh if there are none yet, the refresh key changed, or the cache held the
        whole buffer and the buffer has doubled since (a young buffer, with the same target network).
        """
        assert isinstance(self.replay_buffer, OffOnBufferMixin)
        key = self._lambda_refresh_key()
        cache = self._lambda_cache
        if cache is not None and cache.key == key and not cache.outgrown(self.replay_buffer):
            return cache
        self._lambda_cache = self._compute_lambda_cache(max(n_samples, self._lambda_samples_per_refresh()), key)
        return self._lambda_cache

    def _compute_lambda_cache(self, n_wanted: int, key: int) -> LambdaReturnCache:
        """The lambda-returns of about ``n_wanted`` stored transitions, with the target network of refresh ``key``."""
        raise NotImplementedError

    def _draw_lambda_entries(self, n_samples: int) -> tuple[LambdaReturnCache, np.ndarray]:
        """
        The cache (refreshed first if due) and ``n_samples`` of its entries to train on; computed afresh if everything
        cached was overwritten since the refresh.
        """
        assert isinstance(self.replay_buffer, OffOnBufferMixin)
        cache = self._refreshed_lambda_cache(n_samples)
        entries = cache.draw(n_samples, self.replay_buffer)
        if entries is None:  # everything cached was overwritten since the refresh: compute afresh
            self._lambda_cache = None
            cache = self._refreshed_lambda_cache(n_samples)
            entries = cache.draw(n_samples, self.replay_buffer)
            assert entries is not None
        return cache, entries

    def _draw_prioritized_lambda_entries(self, n_samples: int) -> tuple[LambdaReturnCache, np.ndarray, np.ndarray]:
        """
        With prioritised replay: the cache (refreshed first if due) and ``n_samples`` of its entries drawn in proportion
        to their transitions' priorities (p^alpha, as the buffer's tree holds them: new transitions at the highest so
        far), with replacement, and their importance weights (N P(i))^-beta / max: P(i) the entry's probability among
        the cache's live entries, N their number, the maximum over them. Entries whose transition was overwritten since
        the refresh get probability 0; when none is left the cache is computed afresh.

        Which transitions a refresh computes is decided as without prioritisation (blocks picked uniformly): every
        stored transition keeps its chance of a fresh return, and the priorities decide which returns are trained on.
        """
        buffer = self.replay_buffer
        assert isinstance(buffer, PrioritizedBufferMixin)
        for _ in range(2):
            cache = self._refreshed_lambda_cache(n_samples)
            if cache.tree is None:
                cache.tree = SumTree(len(cache))
                cache.tree.update(np.arange(len(cache)), buffer.tree.values(buffer.leaves(cache.slots, cache.envs)))
            gone = np.flatnonzero(~buffer.holds_transition(cache.added_at))
            if len(gone):
                cache.tree.update(gone, np.zeros(len(gone)))
            if cache.tree.total > 0:
                break
            self._lambda_cache = None  # everything cached was overwritten since the refresh: compute afresh
        entries = cache.tree.sample(n_samples, buffer.rng)
        probabilities = cache.tree.probabilities(entries)
        smallest = cache.tree.min / cache.tree.total
        return cache, entries, ((probabilities / smallest) ** -buffer.beta).astype(np.float32)

    def _update_lambda_priorities(self, cache: LambdaReturnCache, entries: np.ndarray, errors: np.ndarray) -> None:
        """New priorities |error| + epsilon for the trained entries: in the buffer's tree and the cache's."""
        buffer = self.replay_buffer
        assert isinstance(buffer, PrioritizedBufferMixin) and cache.tree is not None
        values = buffer.update_priorities(cache.slots[entries], cache.envs[entries], errors)
        live = buffer.holds_transition(cache.added_at[entries])  # overwritten during the call: stays at 0
        cache.tree.update(entries[live], values[live], check=False)

    def _train_on_lambda_cache(self, gradient_steps: int, batch_size: int) -> None:
        """
        ``gradient_steps`` updates of the online network towards cached lambda-returns (refreshed first if due), drawn
        uniformly or, with prioritised replay, by priority: the loop OffOnDQN and OffOnQRDQN share. The minibatches are
        gathered and uploaded in chunks of several steps; each algorithm turns a chunk into tensors
        (:meth:`_lambda_chunk_tensors`) and a step's rows into its loss (:meth:`_lambda_step_loss`); the losses are read
        back once, at the end.
        """
        assert isinstance(self.replay_buffer, OffOnBufferMixin)
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        prioritized = isinstance(self.replay_buffer, PrioritizedBufferMixin)
        weights = None
        if prioritized:
            cache, entries, weights = self._draw_prioritized_lambda_entries(gradient_steps * batch_size)
        else:
            cache, entries = self._draw_lambda_entries(gradient_steps * batch_size)
        # Listed once per call, and only when clipped (QR-DQN's default clips nothing)
        parameters = self._parameter_list() if self.max_grad_norm is not None else []
        losses, errors = [], []
        steps_per_chunk = self._steps_per_chunk(batch_size)
        for first_step in range(0, gradient_steps, steps_per_chunk):
            n_steps = min(steps_per_chunk, gradient_steps - first_step)
            positions = slice(first_step * batch_size, (first_step + n_steps) * batch_size)
            chunk = entries[positions]
            observations, actions = self.replay_buffer.observations_and_actions(
                cache.slots[chunk], cache.envs[chunk], self._vec_normalize_env
            )
            observations_tensor = obs_as_tensor(observations, self.device)
            actions_tensor, targets, weights_tensor = self._lambda_chunk_tensors(
                actions, cache.returns[chunk], None if weights is None else weights[positions]
            )
            for step in range(n_steps):
                rows = slice(step * batch_size, (step + 1) * batch_size)
                loss, step_errors = self._lambda_step_loss(
                    rows_of(observations_tensor, rows),
                    actions_tensor[rows],
                    targets[rows],
                    None if weights_tensor is None else weights_tensor[rows],
                )
                if step_errors is not None:
                    errors.append(step_errors)

                self.policy.optimizer.zero_grad()
                loss.backward()
                if self.max_grad_norm is not None:
                    th.nn.utils.clip_grad_norm_(parameters, self.max_grad_norm)
                self.policy.optimizer.step()
                losses.append(loss.detach())

        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if prioritized:
            self._update_lambda_priorities(cache, entries, th.cat(errors).cpu().numpy())
        self.logger.record("train/loss", th.stack(losses).mean().item())
        self.logger.record("train/lambda", cache.lam)
        if cache.lambda_spread is not None:  # a lambda chosen per transition: cache.lam is their mean
            self.logger.record("train/lambda_std", cache.lambda_spread)
        self.logger.record("train/trace_cut_fraction", cache.trace_cut_fraction)

    def _lambda_chunk_tensors(
        self, actions: np.ndarray, returns: np.ndarray, weights: np.ndarray | None
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        """A chunk's actions, cached returns and importance weights (None: uniform) as the step loss takes them."""
        raise NotImplementedError

    def _lambda_step_loss(
        self, observations: Any, actions: th.Tensor, targets: th.Tensor, weights: th.Tensor | None
    ) -> tuple[th.Tensor, th.Tensor | None]:
        """
        One gradient step's loss on its rows, importance-weighted when ``weights`` is given, and then also each sample's
        error, whose magnitude becomes its priority (else None).
        """
        raise NotImplementedError

    def _lambda_samples_per_refresh(self) -> int:
        """
        How many transitions will be trained on from one refresh to the next (with ``train_freq`` in steps; in
        episodes, this is unknown and one training call's count is used): each refresh computes about as many
        lambda-returns, so that each is used about once.
        """
        if self.train_freq.unit != TrainFrequencyUnit.STEP:
            return 0
        steps_per_call = self.train_freq.frequency * self.n_envs
        if self.lambda_refresh_interval is not None:
            steps_per_refresh = self.lambda_refresh_interval
        else:
            steps_per_refresh = max(self.target_update_interval // self.n_envs, 1) * self.n_envs
        calls_per_refresh = max(1, math.ceil(steps_per_refresh / steps_per_call))
        gradient_steps = self.gradient_steps if self.gradient_steps >= 0 else steps_per_call
        return calls_per_refresh * gradient_steps * self.batch_size

    def _forward_in_chunks(self, observations: Any, forward: Callable[[Any], tuple[th.Tensor, ...]]) -> list[th.Tensor]:
        """
        ``forward`` (the target network's pass, under ``no_grad``) over a batch of (normalised) observations in the
        buffer's layout, in chunks of :meth:`_lambda_forward_rows` rows; each of its outputs written into one tensor
        for all the rows, left on the device (empty list for no observations). The observations may be an array (or a
        dict of them) or :class:`sb3_offon.common.stored_rows.StoredRows`, which gathers each chunk's rows from the
        buffer as it is read, into one array reused by every chunk: the pass then holds one chunk of observations at a
        time.

        Why the outputs go into tensors made once, rather than into a list of each chunk's outputs concatenated at the
        end: the chunk's outputs are small tensors made after its large temporaries (the frames as floats, the
        activations). Kept, each pins the heap above the temporaries freed before it, and the C allocator, which serves
        temporaries of that size from the heap once it has freed one, grows the heap chunk after chunk instead of
        reusing it: a refresh of 14,000 targets on 4 x 84 x 84 frames left the process 1.09 GB larger that way, 0.04 GB
        larger this way, in the same time (tests/test_stored_rows.py).
        """
        first = next(iter(observations.values())) if isinstance(observations, dict) else observations
        n_rows, rows_per_chunk = len(first), self._lambda_forward_rows()
        results: list[th.Tensor] = []
        with th.no_grad():
            for start in range(0, n_rows, rows_per_chunk):
                rows = slice(start, start + rows_per_chunk)
                parts = forward(obs_as_tensor(rows_of(observations, rows), self.device))
                if not results:
                    results = [th.empty((n_rows, *part.shape[1:]), dtype=part.dtype, device=part.device) for part in parts]
                for result, part in zip(results, parts, strict=True):
                    result[rows] = part
                del parts
        return results

    def _lambda_forward_rows(self) -> int:
        """
        How many next observations the refresh runs through the target network at once: at most
        ``LAMBDA_FORWARD_ROWS``, and at most ``LAMBDA_FORWARD_BYTES`` of float32 observations.

        Larger chunks are slower on a CPU once their activations leave the cache: 32,000 rows through a 256-256 MLP at
        once took 1.5x as long as in chunks of 1,024; NatureCNN on 4x84x84 frames (one thread) took 247 us a row in
        chunks of 594 (64 MiB of floats) and 177-188 us in chunks of 48-128 (the bytes bound gives 74).
        """
        return max(1, min(LAMBDA_FORWARD_ROWS, LAMBDA_FORWARD_BYTES // max(self._observation_bytes(), 1)))
