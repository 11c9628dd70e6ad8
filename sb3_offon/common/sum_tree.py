"""
A sum tree over a replay buffer's priorities, with their minimum: the data structure that proportional prioritised
experience replay samples from (Schaul, Quan, Antonoglou and Silver, "Prioritized Experience Replay", ICLR 2016).

Each of the ``capacity`` leaves holds one transition's priority ``p_i`` (already raised to the power alpha by the
caller). Transition ``i`` is drawn with probability ``p_i / sum_k p_k``: a value ``u`` uniform in ``[0, total)`` falls in
leaf ``i`` when ``sum(p[:i]) <= u < sum(p[:i + 1])``. The smallest positive priority gives prioritised replay the largest
importance-sampling weight, which normalises the others.

Layout: a tree of two levels, as wide as it is deep is costly in Python. The leaves are cut into ``n_blocks`` blocks of
``block_size`` (a power of two near the square root of the capacity; the last block padded with zeros), and each
block's sum and smallest positive leaf are kept. A search takes the running sum over the block sums to find the block,
then the running sum within that block to find the leaf; an update sets the leaves and recomputes the sums of the
blocks it touched from their leaves. Each operation is a handful of vectorised NumPy calls for a whole batch, O(batch x
block_size + n_blocks) work, with no Python loop over samples or levels: on one CPU thread this beats a binary tree's
level-by-level loop, whose log2(capacity) rounds of small NumPy calls cost more than the arithmetic they save, for
every buffer size a DQN uses. Block sums are recomputed from their leaves, never adjusted by a leaf's change, so every
sum is the same function of the leaves whatever the history of updates: no floating-point drift accumulates.

A leaf set to 0 is empty: it is never drawn and does not count for the minimum, because a zero priority marks a slot
that holds no transition (or one that must not be drawn), not the smallest priority of the stored ones.

The arrays are plain NumPy arrays and ints: the object pickles and copies as it is, with the replay buffer that holds it.
"""

from typing import Any

import numpy as np


class SumTree:
    """
    A sum tree and a min tree over ``capacity`` non-negative priorities, updated and searched a batch at a time.

    All leaves start at 0 (empty). See the module's docstring for the layout and the costs.

    :param capacity: the number of leaves (the replay buffer's size): any positive integer
    """

    def __init__(self, capacity: int) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int | np.integer) or capacity < 1:
            raise ValueError(f"The capacity of a SumTree must be a positive integer, got {capacity!r}")
        self.capacity = int(capacity)
        # Blocks of a power of two near sqrt(capacity), at least 16 leaves: the two levels' costs balance there
        self.block_size = max(16, 1 << (int(np.sqrt(self.capacity)) - 1).bit_length())
        self.n_blocks = -(-self.capacity // self.block_size)
        self._leaves = np.zeros(self.n_blocks * self.block_size, dtype=np.float64)
        self._block_sums = np.zeros(self.n_blocks, dtype=np.float64)
        self._block_mins = np.full(self.n_blocks, np.inf, dtype=np.float64)
        self._total = 0.0
        self._min = np.inf
        self._last_positive_block = -1

    def __len__(self) -> int:
        """
        :return: the number of leaves (``capacity``), not counting the padding
        """
        return self.capacity

    def __repr__(self) -> str:
        return f"SumTree(capacity={self.capacity}, total={self.total!r}, min={self.min!r})"

    @property
    def total(self) -> float:
        """
        :return: the sum of all priorities
        """
        return self._total

    @property
    def min(self) -> float:
        """
        :return: the smallest positive priority; +inf if all priorities are 0
        """
        return self._min

    def _check_indices(self, indices: Any) -> np.ndarray:
        indices = np.asarray(indices)
        if indices.size > 0 and not np.issubdtype(indices.dtype, np.integer):
            raise ValueError(f"SumTree indices must be integers, got an array of {indices.dtype}")
        indices = indices.astype(np.int64, copy=False)
        # Negative indices are refused rather than counted from the end: they are a caller's bug, not a convenience
        if indices.size > 0 and (indices.min() < 0 or indices.max() >= self.capacity):
            raise ValueError(
                f"SumTree indices must lie in [0, {self.capacity}), got values from {indices.min()} to {indices.max()}"
            )
        return indices

    def values(self, indices: np.ndarray) -> np.ndarray:
        """
        The priorities of some leaves.

        :param indices: leaf indices in ``[0, capacity)``, any shape
        :return: their priorities (float64, same shape)
        """
        return self._leaves[self._check_indices(indices)]

    def probabilities(self, indices: np.ndarray) -> np.ndarray:
        """
        The probabilities with which ``sample_proportional`` draws some leaves (and, on average, ``sample``).

        :param indices: leaf indices in ``[0, capacity)``, any shape
        :return: ``priority / total`` for each (float64, same shape)
        """
        total = self.total
        if total <= 0.0:
            raise ValueError("The priorities of the SumTree are all 0: no leaf has a probability")
        return self.values(indices) / total

    def update(self, indices: np.ndarray, priorities: np.ndarray, check: bool = True) -> None:
        """
        Set the priorities of a batch of leaves, then recompute the sums of their blocks.

        A priority of 0 empties its leaf: it is never drawn, and it does not count for ``min``.

        :param indices: leaf indices in ``[0, capacity)``; where one repeats, the last priority given for it wins, as
            with a loop of single updates
        :param priorities: the new priorities (already raised to the power alpha), finite and non-negative, one per
            index (or one for all)
        :param check: check the indices and priorities (False: a caller that made them so saves the checks' cost; one
            priority per index, as int64 and float64 arrays)
        """
        if not check:
            self._set(np.asarray(indices).ravel(), np.asarray(priorities, dtype=np.float64).ravel())
            return
        indices = self._check_indices(indices).ravel()
        priorities = np.asarray(priorities, dtype=np.float64)
        try:
            priorities = np.broadcast_to(priorities.ravel() if priorities.ndim > 0 else priorities, indices.shape)
        except ValueError:
            raise ValueError(
                f"SumTree.update needs one priority per index: got {priorities.size} priorities for {indices.size} indices"
            ) from None
        if indices.size == 0:
            return
        if not np.all(np.isfinite(priorities)):
            raise ValueError(f"SumTree priorities must be finite, got {priorities[~np.isfinite(priorities)][:5]}")
        if np.any(priorities < 0.0):
            raise ValueError(f"SumTree priorities must be non-negative, got {priorities[priorities < 0.0][:5]}")

        self._set(indices, priorities)

    def _set(self, indices: np.ndarray, priorities: np.ndarray) -> None:
        """:meth:`update` of checked, flat indices and priorities of the same length."""
        if indices.size == 0:
            return
        # NumPy does not promise which value of a repeated index a fancy assignment keeps: keep the last explicitly
        # (np.unique of the reversed indices returns each one's first occurrence there, its last one in the given order)
        leaves, last = np.unique(indices[::-1], return_index=True)
        self._leaves[leaves] = priorities[::-1][last]
        blocks = leaves // self.block_size  # sorted, as the leaves are: each block once
        blocks = blocks[np.concatenate(([True], blocks[1:] != blocks[:-1]))]
        block_leaves = self._leaves[blocks[:, None] * self.block_size + np.arange(self.block_size)]
        self._block_sums[blocks] = block_leaves.sum(axis=1)
        self._block_mins[blocks] = np.where(block_leaves > 0.0, block_leaves, np.inf).min(axis=1)
        self._total = float(self._block_sums.sum())
        self._min = float(self._block_mins.min())
        positive = np.flatnonzero(self._block_sums > 0.0)
        self._last_positive_block = int(positive[-1]) if len(positive) else -1

    def find(self, prefix_sums: np.ndarray) -> np.ndarray:
        """
        For each value ``u``, the leaf ``i`` with ``sum(p[:i]) <= u < sum(p[:i + 1])``, found by one descent of the tree
        for all values at once.

        The leaf found always has a positive priority: where rounding would lead the descent past the last positive
        leaf of a subtree (``u`` at or just below ``total``, or ``u`` less a left sum landing at or beyond the right
        sum), it stops at that last positive leaf instead of entering an empty subtree. ``u = total`` is accepted and
        gives the last positive leaf.

        :param prefix_sums: values in ``[0, total]``, any shape
        :return: leaf indices (int64, same shape)
        """
        values = np.asarray(prefix_sums, dtype=np.float64)
        total = self.total
        if total <= 0.0:
            raise ValueError("The priorities of the SumTree are all 0: there is no leaf to find")
        bad = ~((values >= 0.0) & (values <= total))  # also catches NaN
        if np.any(bad):
            raise ValueError(f"SumTree.find needs values in [0, total = {total!r}], got {values[bad][:5]}")

        flat = values.ravel()
        found = np.empty(flat.shape, dtype=np.int64)
        # In chunks, so that the rows of leaves gathered stay small (a chunk x block_size array)
        rows_per_chunk = max(1, 2**20 // self.block_size)
        for start in range(0, len(flat), rows_per_chunk):
            found[start : start + rows_per_chunk] = self._find(flat[start : start + rows_per_chunk])
        return found.reshape(values.shape)

    def _find(self, values: np.ndarray) -> np.ndarray:
        """:meth:`find` for a flat array of checked values."""
        # The block: the first whose running sum exceeds u. Rounding can take u at or past the last running sum: the
        # last block with a positive sum is the answer then
        running = np.cumsum(self._block_sums)
        blocks = np.searchsorted(running, values, side="right")
        blocks = np.minimum(blocks, self._last_positive_block)
        # Skip empty blocks that rounding may have stopped at (their running sum equals the previous one's)
        empty = self._block_sums[blocks] <= 0.0
        if np.any(empty):
            positive = np.flatnonzero(self._block_sums > 0.0)
            blocks[empty] = positive[np.minimum(np.searchsorted(positive, blocks[empty]), len(positive) - 1)]
        # The leaf: within the block, the first whose running sum exceeds what is left of u. Counting the running sums
        # at or below it skips the empty leaves (their running sum equals the previous one's); what is left is clipped
        # at 0, so that rounding below the block's start cannot land on an empty first leaf
        left = np.maximum(values - (running[blocks] - self._block_sums[blocks]), 0.0)
        rows = self._leaves[blocks[:, None] * self.block_size + np.arange(self.block_size)]
        leaves = np.count_nonzero(np.cumsum(rows, axis=1) <= left[:, None], axis=1)
        # Rounding can also take what is left at or past the block's sum: its last positive leaf is the answer then
        past = leaves >= self.block_size
        if np.any(past):
            leaves[past] = self.block_size - 1 - np.argmax(rows[past][:, ::-1] > 0.0, axis=1)
        return blocks * self.block_size + leaves

    def _check_batch_size(self, batch_size: int) -> float:
        if isinstance(batch_size, bool) or not isinstance(batch_size, int | np.integer) or batch_size < 1:
            raise ValueError(f"The batch size must be a positive integer, got {batch_size!r}")
        total = self.total
        if total <= 0.0:
            raise ValueError("The priorities of the SumTree are all 0: there is nothing to sample")
        return total

    def sample(self, batch_size: int, rng: np.random.Generator) -> np.ndarray:
        """
        Stratified proportional sampling (as Schaul et al. 2016 sample their minibatches): ``[0, total)`` is split into
        ``batch_size`` equal segments and one value is drawn uniformly in each. Each leaf is drawn with probability
        ``p_i / total`` on average over the batch, with less variance than independent draws; draw ``k`` comes from
        segment ``k``, so the indices come out in non-decreasing order.

        :param batch_size: the number of indices to draw
        :param rng: the random number generator
        :return: leaf indices (int64), all of positive priority
        """
        total = self._check_batch_size(batch_size)
        segment = total / batch_size
        # The last segment's end may round above total: clipped (the values are in range, _find needs no check)
        values = np.minimum((np.arange(batch_size, dtype=np.float64) + rng.random(batch_size)) * segment, total)
        return self._find(values)

    def sample_proportional(self, batch_size: int, rng: np.random.Generator) -> np.ndarray:
        """
        Independent proportional sampling: each index is drawn with probability ``p_i / total``, independently of the
        others (with replacement, no strata).

        :param batch_size: the number of indices to draw
        :param rng: the random number generator
        :return: leaf indices (int64), all of positive priority
        """
        total = self._check_batch_size(batch_size)
        return self._find(np.minimum(rng.random(batch_size) * total, total))
