"""
Which stored transitions a refresh of the lambda-return cache computes, and what their traces need of the replay buffer
(:class:`LambdaLayout`): blocks of consecutive transitions (:func:`choose_blocks`), laid out padded, with where each
trace goes on and where no value follows. Everything but the target network's values, which differ between a scalar
critic (:mod:`sb3_offon.common.lambda_returns`) and a distributional one
(:mod:`sb3_offon.offon_qrdqn.quantile_lambda_returns`), and which the rules that choose lambda read
(:mod:`sb3_offon.common.lambda_choice`).
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from sb3_offon.common.buffers import OffOnBufferMixin


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
