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


def wants_whole_buffer(n_envs: int, first: int, n_stored: int, n_wanted: int) -> bool:
    """Whether ``n_wanted`` transitions are at least all that is stored: then each env column is one block."""
    return n_wanted >= n_envs * (n_stored - first)


def choose_blocks(
    n_envs: int, first: int, n_stored: int, block_size: int, n_wanted: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Blocks of consecutive stored transitions (in chronological indices) that hold about ``n_wanted`` transitions.

    Each env column's valid range ``[first, n_stored)`` is cut into blocks of ``block_size`` on a grid with a random
    offset (so block ends move from one refresh to the next); blocks are then picked at random without replacement until
    they hold ``n_wanted`` transitions, so a transition is in the cache at most once, and uniformly at random in blocks.
    When they would hold the whole buffer anyway, each env column is one block: no trace is cut at a block's end.

    :return: per block, its env column, first chronological index and length
    """
    n_valid = n_stored - first
    if n_valid <= 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    if wants_whole_buffer(n_envs, first, n_stored, n_wanted):
        return np.arange(n_envs), np.full(n_envs, first), np.full(n_envs, n_valid)
    offset = np.random.randint(block_size)
    cuts = np.arange(first + offset, n_stored, block_size)
    bounds = np.unique(np.concatenate(([first], cuts, [n_stored])))
    column_starts, column_lengths = bounds[:-1], np.diff(bounds)
    n_column_blocks = len(column_starts)
    picked = np.random.permutation(n_envs * n_column_blocks)
    lengths = column_lengths[picked % n_column_blocks]
    n_picked = int(np.searchsorted(np.cumsum(lengths), n_wanted)) + 1
    picked = picked[:n_picked]
    return picked // n_column_blocks, column_starts[picked % n_column_blocks], lengths[:n_picked]


@dataclass
class LambdaLayout:
    """
    The stored transitions of one refresh, laid out in blocks, and what their traces need of the buffer (everything but
    the target network's values, which differ between a scalar and a distributional critic).

    Arrays named ``padded`` are shaped (blocks, width), a block's transitions in chronological order from column 0;
    the others hold the valid cells only, in the order of ``padded[valid]``.

    :param valid: which cells of the padded layout hold a transition
    :param slots: the transitions' slots in the replay buffer
    :param envs: their env columns
    :param added_at: their absolute add indices
    :param inputs: :meth:`OffOnBufferMixin.lambda_inputs` of the transitions
    :param stride: how far ahead a transition's trace goes on (the buffer's ``n_steps``)
    :param goes_on: (padded) the trace of the transition can go on to the one ``stride`` steps later: its episode went
        on past its window and that transition is in the block
    :param no_value_after: no value follows the transition where its trace stops (a termination; with
        ``cut_is_terminal``, a cut episode's end too)
    :param whole_buffer: whether the blocks are every transition stored (each env's history one block)
    """

    valid: np.ndarray
    slots: np.ndarray
    envs: np.ndarray
    added_at: np.ndarray
    inputs: dict[str, Any]
    stride: int
    goes_on: np.ndarray
    no_value_after: np.ndarray
    whole_buffer: bool

    def padded(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """``values`` (one per transition, with any trailing shape) in the padded layout, ``fill`` elsewhere."""
        result = np.full((*self.valid.shape, *np.shape(values)[1:]), fill, dtype=np.result_type(values, fill))
        result[self.valid] = values
        return result

    def padded_rewards(self) -> np.ndarray:
        """(padded, float64) R: each transition's reward, discounted over its window of k steps; 0 elsewhere."""
        return self.padded(self.inputs["rewards"].astype(np.float64))

    def padded_discounts(self) -> np.ndarray:
        """(padded) D: gamma, or gamma^k over a window of k steps; 1 elsewhere."""
        return self.padded(self.inputs["discounts"], fill=1.0)

    def padded_value_after(self, next_values: np.ndarray) -> np.ndarray:
        """(padded, float64) What follows a transition whose trace stops at it: V(s_next), or 0 where no value follows."""
        return self.padded(np.where(self.no_value_after, 0.0, next_values).astype(np.float64))

    def trace(self, greedy_actions: np.ndarray, qlearning_prob: float) -> np.ndarray:
        """(padded) c: 1 where the action recorded after the transition's window is the greedy one, else 1 - delta2."""
        next_actions = self.inputs["next_actions"].reshape(-1)
        return self.padded(np.where(greedy_actions == next_actions, 1.0, 1.0 - qlearning_prob), fill=1.0)

    def trace_cut_fraction(self, trace: np.ndarray) -> float:
        """The share of the continuations whose trace weight is below 1."""
        n_goes_on = int(np.count_nonzero(self.goes_on))
        return float(np.count_nonzero(self.goes_on & (trace < 1.0))) / n_goes_on if n_goes_on else 0.0


def no_value_after(inputs: dict[str, Any], cut_is_terminal: bool) -> np.ndarray:
    """
    Where no value follows the last step of a transition's window (:meth:`OffOnBufferMixin.lambda_inputs`): a
    termination; with ``cut_is_terminal`` (``mc_truncation="terminal"``) an episode cut there too, but never the newest
    transition of an episode still running (its episode goes on).
    """
    stops = inputs["terminated"]
    if cut_is_terminal:
        stops = stops | ((inputs["next_actions"] < 0) & ~inputs["running_newest"])
    return stops


def lambda_layout(
    buffer: OffOnBufferMixin, n_wanted: int, block_size: int, gamma: float, cut_is_terminal: bool, env: Any = None
) -> LambdaLayout:
    """
    About ``n_wanted`` stored transitions in blocks (:func:`choose_blocks`) and what their lambda-returns need of the
    buffer. The parameters are those of :func:`compute_lambda_returns`.
    """
    oldest, n_stored, first = buffer.chronology()
    block_envs, block_starts, block_lengths = choose_blocks(buffer.n_envs, first, n_stored, block_size, n_wanted)
    width = int(block_lengths.max()) if len(block_lengths) else 0
    steps = np.arange(width)
    valid = steps < block_lengths[:, None]
    chronological = block_starts[:, None] + steps
    slots = ((oldest + chronological) % buffer.buffer_size)[valid]
    envs = np.broadcast_to(block_envs[:, None], valid.shape)[valid]

    inputs = buffer.lambda_inputs(slots, envs, gamma, env)
    next_actions = inputs["next_actions"].reshape(-1)
    # Where the trace goes on: the next transition (one-step buffer) or the one after the n-step window
    stride = buffer.n_steps
    goes_on = np.zeros(valid.shape, dtype=bool)
    goes_on[valid] = next_actions >= 0
    goes_on[:, :-stride] &= valid[:, stride:]
    goes_on[:, -stride:] = False
    return LambdaLayout(
        valid=valid,
        slots=slots,
        envs=envs,
        added_at=buffer._n_adds - n_stored + chronological[valid],
        inputs=inputs,
        stride=stride,
        goes_on=goes_on,
        no_value_after=no_value_after(inputs, cut_is_terminal),
        whole_buffer=wants_whole_buffer(buffer.n_envs, first, n_stored, n_wanted),
    )


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
