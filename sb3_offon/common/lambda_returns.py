"""
The lambda-returns of OffOnDQN's ``mc_mixing="lambda"``: computed backwards over blocks of replayed transitions with
one batched pass of the target network, and cached until the target network changes (DQN(lambda), Daley & Amato 2019).

For a transition t (``gamma`` the discount, ``lam`` = delta1, ``delta2`` the trace-cut weight):

- G_t = r_t where t terminated its episode;
- G_t = r_t + gamma * V(s_{t+1}) where t was cut (a time limit, a reset) or is the newest transition of an episode still
  running, or of its block;
- otherwise G_t = r_t + gamma * [(1 - lam * c_{t+1}) * V(s_{t+1}) + lam * c_{t+1} * G_{t+1}], where c_{t+1} = 1 if
  a_{t+1} = argmax_a Q_target(s_{t+1}, a), and 1 - delta2 otherwise;

with V(s) = max_a Q_target(s, a). Each G_t is x_t + a_t * G_{t+1} with x_t and a_t known once V is: a linear recurrence,
run backwards for all blocks at once by :func:`backward_recurrence`.

With an n-step buffer (``n_steps`` = n > 1), the steps above are n-step windows, as in n-step DQN: r_t becomes
R_t = sum_{i<k} gamma^i r_{t+i} over the k <= n steps of t's window (k < n where its episode did not go on), gamma
becomes gamma^k, s_{t+1} becomes s_{t+k}, and the trace goes on to G_{t+n} with c_{t+n} (the action recorded at s_{t+n}
against the greedy one there): the lambda-return over the n-, 2n-, 3n-step returns, whose lambda = 0 end is n-step DQN's
target. Actions inside a window are not checked against the greedy policy, as n-step DQN does not check them.
"""

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sb3_offon.common.buffers import OffOnBufferMixin
from sb3_offon.common.lambda_choice import PER_REFRESH_CHOICES, choose_lambda, refresh_lambda
from sb3_offon.common.lambda_layout import LambdaLayout, lambda_layout

# Maps a batch of next observations (normalised, in the buffer's layout) to (max_a Q_target(s', a), argmax_a) as NumPy
TargetValueFn = Callable[[Any], tuple[np.ndarray, np.ndarray]]


def backward_recurrence(inputs: np.ndarray, coefficients: np.ndarray, stride: int = 1) -> np.ndarray:
    """
    y_t = x_t + a_t * y_{t+stride} along the last axis, with y = 0 past the end, for every row at once.

    The coefficients vary from step to step (with Peng's and intermediate trace cuts, a_t takes any value in
    [0, gamma * lam]), so a constant-coefficient filter (``scipy.signal.lfilter``) does not apply. Each step is the
    affine map z -> x_t + a_t * z, and maps compose associatively: doubling the span of the composed maps ceil(log2(T))
    times (a Hillis-Steele scan) gives every y_t in O(T log T) vectorised operations, with no Python loop over steps.
    A coefficient of 0 (an episode's end, a cut trace) starts a new segment.

    With a stride s > 1, the steps t, t + s, t + 2s, ... form s interleaved recurrences of stride 1: the last axis is
    padded to a multiple of s and folded so that each becomes a row of its own.

    :param inputs: x, shaped (..., T)
    :param coefficients: a, the same shape
    :param stride: s, how far ahead each step's successor lies
    :return: y as float64, the same shape
    """
    if stride > 1:
        length = np.shape(inputs)[-1]
        padding = [(0, 0)] * (np.ndim(inputs) - 1) + [(0, -length % stride)]

        def fold(array: np.ndarray) -> np.ndarray:  # (..., T) -> (..., s, ceil(T / s)): row r holds t = r, r + s, ...
            padded = np.pad(np.asarray(array, dtype=np.float64), padding)
            return np.swapaxes(padded.reshape(*padded.shape[:-1], padded.shape[-1] // stride, stride), -1, -2)

        folded = backward_recurrence(fold(inputs), fold(coefficients))
        unfolded = np.swapaxes(folded, -1, -2)
        return unfolded.reshape(*unfolded.shape[:-2], unfolded.shape[-2] * stride)[..., :length]
    values = np.array(inputs, dtype=np.float64)
    spans = np.array(coefficients, dtype=np.float64)
    length = values.shape[-1]
    shift = 1
    while shift < length:
        # After this round, values[t] = x_t + ... over 2 * shift steps and spans[t] the product of their coefficients
        values[..., :-shift] += spans[..., :-shift] * values[..., shift:]
        spans[..., :-shift] *= spans[..., shift:]
        spans[..., length - shift :] = 0.0  # nothing lies past the end
        shift *= 2
    return values


@dataclass
class LambdaReturnCache:
    """
    The lambda-returns of a set of stored transitions, computed with one target network and one (lam, delta2).

    :param slots: the transitions' slots in the replay buffer
    :param envs: their env columns
    :param added_at: their absolute add indices (to tell a slot overwritten since)
    :param returns: their lambda-returns, float32, in the units of the rewards the networks learn from (a tensor on
        the device for the per-call targets of OffOnQRDQN's ``lambda_cache=False``)
    :param key: what identifies the target network they were computed with (OffOnDQN's refresh key)
    :param lam: lambda (delta1) of the refresh
    :param qlearning_prob: delta2 of the refresh
    :param trace_cut_fraction: the share of the continuations whose trace weight c_{t+1} was below 1
    :param whole_buffer: whether they are every transition stored at the refresh (each env's history one block)
    :param lambda_spread: with a lambda chosen per transition (``lambda_choice``), the standard deviation of the chosen
        lambdas (``lam`` is then their mean); None with a fixed lambda
    """

    slots: np.ndarray
    envs: np.ndarray
    added_at: np.ndarray
    returns: Any  # np.ndarray, or a torch tensor (see above)
    key: int
    lam: float
    qlearning_prob: float
    trace_cut_fraction: float
    whole_buffer: bool = False
    lambda_spread: float | None = None
    order: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    # Prioritised replay: a sum tree over the entries (their transitions' priorities), built at the first draw
    tree: Any = None
    cursor: int = 0
    _newest_added_at: int | None = None

    def __len__(self) -> int:
        return len(self.returns)

    def outgrown(self, buffer: OffOnBufferMixin) -> bool:
        """
        Whether the cache held the whole buffer and the buffer now holds at least twice as many transitions: then the
        transitions added since outnumber the cached ones, and training on the cache alone would starve them.
        """
        if not self.whole_buffer:
            return False
        _, n_stored, first = buffer.chronology()
        return buffer.n_envs * (n_stored - first) >= 2 * len(self)

    def draw(self, n_samples: int, buffer: OffOnBufferMixin) -> np.ndarray | None:
        """
        ``n_samples`` entries, without replacement while the cache lasts (in a random order drawn from NumPy's global
        RNG, as SB3 samples), skipping transitions the buffer has overwritten since the refresh.

        :return: entry indices, or None when too few of the cached transitions are still stored (refresh then)
        """
        # The newest cached transition is the last one the buffer overwrites: if it is gone, they all are. Checked on
        # it alone, and below on the entries drawn, so that a call costs O(n_samples), not O(cache) (a cache holds a
        # refresh's worth of transitions, 32,000 with one gradient step of 32 per env step and a target update every
        # 1,000); the whole cache is checked only when a new pass over it begins
        if len(self.added_at) == 0 or not buffer.holds_transition(np.array(self.newest_added_at())):
            return None
        drawn: list[np.ndarray] = []
        n_drawn = 0
        while n_drawn < n_samples:
            if self.cursor >= len(self.order):
                # A new pass over the live entries, in a new random order
                live = np.flatnonzero(buffer.holds_transition(self.added_at))
                self.order = live[np.random.permutation(len(live))]
                self.cursor = 0
            taken = self.order[self.cursor : self.cursor + n_samples - n_drawn]
            self.cursor += len(taken)
            # Entries of the current pass may have been overwritten since it began
            taken = taken[buffer.holds_transition(self.added_at[taken])]
            drawn.append(taken)
            n_drawn += len(taken)
        return np.concatenate(drawn)

    def newest_added_at(self) -> int:
        """The add index of the newest cached transition (computed once: the cache does not change)."""
        if self._newest_added_at is None:
            self._newest_added_at = int(self.added_at.max())
        return self._newest_added_at


def compute_lambda_returns(
    buffer: OffOnBufferMixin,
    target_values: TargetValueFn,
    n_wanted: int,
    block_size: int,
    gamma: float,
    lam: float,
    qlearning_prob: float,
    cut_is_terminal: bool,
    key: int,
    env: Any = None,
    choice: str = "fixed",
) -> LambdaReturnCache:
    """
    The lambda-returns of about ``n_wanted`` stored transitions (see the module's docstring), in blocks.

    :param buffer: the Off-On replay buffer
    :param target_values: V and the greedy actions of the target network, for a batch of next observations
    :param n_wanted: how many transitions to cover (the whole buffer, in one block per env, if it holds no more)
    :param block_size: the length of a block: the trace of a block's last transition is cut there (bootstrapped; with
        n-step windows, of each transition whose successor n steps on lies past the block's end)
    :param gamma: the discount factor
    :param lam: lambda (delta1)
    :param qlearning_prob: delta2: the trace weight after a non-greedy action is 1 - delta2
    :param cut_is_terminal: ``mc_truncation="terminal"``: an episode cut by a time limit or a reset has no value after
        its last step (the newest transition of a running episode, and a block's last, still bootstrap)
    :param key: the refresh key to store
    :param env: the VecNormalize wrapper, if any, to normalise observations and rewards with
    :param choice: ``"fixed"``: ``lam`` for every transition; otherwise a rule of :mod:`sb3_offon.common.lambda_choice`
        that chooses a lambda per transition (``lam`` unused) or one per refresh (``lam`` where it cannot choose)
    """
    layout = lambda_layout(buffer, n_wanted, block_size, gamma, cut_is_terminal, env)
    next_values, greedy_actions = target_values(layout.inputs["next_observations"])
    trace = layout.trace(greedy_actions, qlearning_prob)  # c_{t+1} (c_{t+n} with n-step windows)
    chosen = None
    if choice in PER_REFRESH_CHOICES:
        lam = refresh_lambda(choice, layout, next_values, trace, fallback=lam)
    if choice == "fixed" or choice in PER_REFRESH_CHOICES:
        returns = scalar_lambda_returns(layout, next_values, trace, lam)
    else:

        def returns_of(lambdas: np.ndarray) -> np.ndarray:
            return scalar_lambda_returns(layout, next_values, trace, lambdas)

        returns, chosen = choose_lambda(choice, returns_of, (layout.goes_on & (trace > 0))[layout.valid])
    return LambdaReturnCache(
        slots=layout.slots,
        envs=layout.envs,
        added_at=layout.added_at,
        returns=returns.astype(np.float32),
        key=key,
        lam=lam if chosen is None else chosen.mean,
        qlearning_prob=qlearning_prob,
        trace_cut_fraction=layout.trace_cut_fraction(trace),
        whole_buffer=layout.whole_buffer,
        lambda_spread=None if chosen is None else chosen.spread,
    )


def scalar_lambda_returns(layout: LambdaLayout, next_values: np.ndarray, trace: np.ndarray, lam: Any) -> np.ndarray:
    """
    The lambda-returns of a layout's transitions (the module's docstring), from V of their next states and their trace.

    :param layout: the transitions and what their traces need (:func:`lambda_layout`)
    :param next_values: V(s_next) per transition
    :param trace: (padded) c per transition (:meth:`LambdaLayout.trace`)
    :param lam: lambda: a float, or an array of K lambdas shaped (K, 1, 1) for the returns of each at once
    :return: float64, (transitions,), or (K, transitions) for K lambdas
    """
    goes_on, discounts = layout.goes_on, layout.padded_discounts()
    padded_values = layout.padded(next_values.astype(np.float64))
    bootstrap = np.where(goes_on, (1.0 - lam * trace) * padded_values, layout.padded_value_after(next_values))
    returns = backward_recurrence(
        layout.padded_rewards() + discounts * bootstrap, np.where(goes_on, discounts * lam * trace, 0.0), stride=layout.stride
    )
    return returns[..., layout.valid]
