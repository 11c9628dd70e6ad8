"""
Lambda-returns stated as horizons, and drawn as horizons without a cache.

:func:`lambda_for_horizon` is the lambda whose lambda-return contracts like an n-step return: the lambda-return's
bootstrap weight is sum_k (1 - lam) lam^(k-1) gamma^k = gamma (1 - lam) / (1 - gamma lam), and setting it equal to
gamma^n gives lam_n = (1 - gamma^(n-1)) / (1 - gamma^n) (Daley et al., "Averaging n-step returns reduces variance in
reinforcement learning", ICML 2024: among returns with that contraction, such averages have lower variance than the
n-step return). With gamma 0.99: lam_3 = 0.670, lam_5 = 0.804, lam_10 = 0.904; lambda 0.9 contracts like a 9.6-step
return.

:func:`sample_horizon_returns` is the lambda-return without a cache (OffOnQRDQN's ``lambda_cache=False``): at each
training call, transitions are drawn uniformly from the whole buffer, as SB3's ``sample()`` draws them, and each gets a
horizon k drawn from the lambda-return's weights, (1 - lam) lam^(k-1) for k < K and lam^(K-1) for the longest horizon
K; its target is the k-step return r_t + ... + gamma^(k-1) r_(t+k-1) + gamma^k Z(s_(t+k), a*), computed with the
target network of the moment. An episode that ends before k steps gives its remaining weight to its end: the
Monte-Carlo return after a termination, the bootstrap from its last state after a cut (a time limit, a reset, the newest
transition of a running episode), as in the cached lambda-returns (with ``optimize_memory_usage`` a time limit is
stored as a termination, as SB3 stores it). The quantile loss being linear in the target law,
the draw is an unbiased sample of the loss towards the mixture, the argument of the cached ``lambda_form="sampled"``;
here a transition gets a fresh draw each time it is sampled instead of one per refresh. Peng's Q(lambda) only: the
trace is never cut (a cut would need the greedy action at every state on the way). With n-step windows (``n_steps`` =
n), horizons are whole windows, n, 2n, ..., and lambda = 0 is n-step QR-DQN's target on n-step QR-DQN's samples.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from sb3_offon.common.buffers import OffOnBufferMixin
from sb3_offon.common.lambda_layout import no_value_after


def lambda_for_horizon(n: float, gamma: float) -> float:
    """
    The lambda whose lambda-return contracts like an ``n``-step return with discount ``gamma`` (see the module's
    docstring): ``OffOnQRDQN(..., mc_initial_prob=lam, mc_final_prob=lam)`` with ``lam = lambda_for_horizon(3, 0.99)``.

    With n-step windows (``n_steps`` = m > 1) lambda weighs windows, not steps: the lambda whose return contracts like
    an n-step one is then ``lambda_for_horizon(n / m, gamma ** m)`` (n = 3, m = 3: lambda 0, the 3-step target).

    :param n: the horizon, at least 1 (1: lambda 0, the one-step target)
    :param gamma: the discount factor, in (0, 1)
    :return: lam_n = (1 - gamma^(n-1)) / (1 - gamma^n)
    :raises ValueError: naming the bad parameter
    """
    if not 0.0 < gamma < 1.0:
        raise ValueError(f"`gamma` must be in (0, 1), got {gamma!r}")
    if not n >= 1:
        raise ValueError(f"`n` must be at least 1, got {n!r}")
    return float((1.0 - gamma ** (n - 1)) / (1.0 - gamma**n))


def draw_horizons(rng: np.random.Generator, lam: float, n_samples: int, longest: int) -> np.ndarray:
    """
    ``n_samples`` horizons (in windows) from the lambda-return's weights: k with probability (1 - lam) lam^(k-1) for
    k < ``longest``, and lam^(longest - 1) for ``longest``.

    :param rng: the generator to draw from (the model's own, saved with it)
    :param lam: lambda, in [0, 1]
    :param n_samples: how many
    :param longest: the longest horizon K, at least 1
    :return: int64 horizons in [1, K]
    """
    if lam <= 0.0:
        return np.ones(n_samples, dtype=np.int64)
    if lam >= 1.0:
        return np.full(n_samples, longest, dtype=np.int64)
    return np.minimum(rng.geometric(1.0 - lam, size=n_samples), longest).astype(np.int64)


@dataclass
class HorizonSamples:
    """
    Transitions drawn uniformly from the buffer, each with its drawn horizon's return, before the bootstrap law.

    :param slots: the transitions' slots in the replay buffer
    :param envs: their env columns
    :param added_at: their absolute add indices
    :param rewards: sum_(i<k) gamma^i r_(t+i) over each transition's horizon k (shortened where its episode stopped)
    :param discounts: gamma^k, multiplied by 0 where no value follows (a termination; with ``cut_is_terminal`` a cut)
    :param next_observations: s_(t+k), normalised as ``sample()`` normalises them, as
        :class:`sb3_offon.common.stored_rows.StoredRows` (read by chunks, or ``np.asarray`` for every row at once)
    :param horizons: k, in steps
    """

    slots: np.ndarray
    envs: np.ndarray
    added_at: np.ndarray
    rewards: np.ndarray
    discounts: np.ndarray
    next_observations: Any
    horizons: np.ndarray


def sample_horizon_returns(
    buffer: OffOnBufferMixin,
    n_samples: int,
    batch_size: int,
    lam: float,
    longest: int,
    gamma: float,
    cut_is_terminal: bool,
    rng: np.random.Generator,
    env: Any = None,
) -> HorizonSamples:
    """
    ``n_samples`` transitions drawn as ``n_samples / batch_size`` calls of SB3's ``sample(batch_size)`` draw them
    (uniformly over the stored slots and envs, from NumPy's global RNG, in the same order: each minibatch's slots, then
    its env indices), each with a horizon drawn from ``rng`` (see the module's docstring).

    :param buffer: the Off-On replay buffer
    :param n_samples: how many transitions (a multiple of ``batch_size``, or fewer than it)
    :param batch_size: the size of the minibatches they are drawn as
    :param lam: lambda
    :param longest: the longest horizon in steps (OffOnQRDQN's ``lambda_block_size``), rounded down to whole windows
        of the buffer's ``n_steps``, at least one window
    :param gamma: the discount factor
    :param cut_is_terminal: ``mc_truncation="terminal"``: no value after a cut episode's last step
    :param rng: the generator of the horizons
    :param env: the VecNormalize wrapper, if any, to normalise observations and rewards with
    """
    slot_parts, env_parts = [], []
    for start in range(0, n_samples, batch_size):
        size = min(batch_size, n_samples - start)
        slot_parts.append(buffer._draw_slots(size))
        # SB3 draws the env indices after the slots; with one env that draw leaves the RNG alone
        env_parts.append(np.random.randint(0, buffer.n_envs, size=size) if buffer.n_envs > 1 else np.zeros(size, np.int64))
    slots, envs = np.concatenate(slot_parts), np.concatenate(env_parts)
    stride = buffer.n_steps
    horizons = draw_horizons(rng, lam, n_samples, max(longest // stride, 1)) * stride
    inputs = buffer.lambda_inputs(slots, envs, gamma, env, lengths=horizons)
    oldest, n_stored, _ = buffer.chronology()
    return HorizonSamples(
        slots=slots,
        envs=envs,
        added_at=buffer._n_adds - n_stored + (slots - oldest) % buffer.buffer_size,
        rewards=inputs["rewards"],
        discounts=np.where(no_value_after(inputs, cut_is_terminal), 0.0, inputs["discounts"]),
        next_observations=inputs["next_observations"],
        horizons=inputs["lengths"],
    )
