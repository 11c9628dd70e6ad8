"""
A sum tree (with a min tree beside it) over a replay buffer's priorities: the data structure that proportional prioritised
experience replay samples from (Schaul, Quan, Antonoglou and Silver, "Prioritized Experience Replay", ICLR 2016).

Each of the ``capacity`` leaves holds one transition's priority ``p_i`` (already raised to the power alpha by the
caller). Transition ``i`` is drawn with probability ``p_i / sum_k p_k``: a value ``u`` uniform in ``[0, total)`` falls in
leaf ``i`` when ``sum(p[:i]) <= u < sum(p[:i + 1])``, and the tree finds that leaf by descending from the root, going
left when ``u`` is below the left child's sum and right (less that sum) otherwise. The min tree gives the smallest
positive priority, from which prioritised replay computes the largest importance-sampling weight that normalises the
others.

Layout: the leaves are padded to the next power of two ``P >= capacity``; both trees are flat float64 arrays of
``2 P - 1`` nodes in 0-based heap order: node 0 is the root, node ``n`` has children ``2 n + 1`` and ``2 n + 2`` and
parent ``(n - 1) // 2``, and leaf ``i`` is node ``P - 1 + i``. The padded leaves hold 0 in the sum tree and +inf in the
min tree, so they are never drawn and never the minimum. A leaf set to 0 is treated the same way, as empty: its
min-tree entry is +inf, because a zero priority marks a slot that holds no transition (or one that must not be drawn),
not the smallest priority of the stored ones.

Costs: ``update`` sets a whole batch of leaves and recomputes their ancestors one level at a time; ``find``, ``sample``
and ``sample_proportional`` descend one level at a time for all values at once. Each is O(batch log capacity) work in
NumPy, with a Python loop only over the log2(P) levels, and memory is 2 x (2 P - 1) float64s (32 MiB for a million
transitions). Parents are recomputed from their two children, never adjusted by the change of a leaf, so every node is
the same function of the leaves whatever the history of updates: no floating-point drift accumulates.

The trees are plain NumPy arrays and ints: the object pickles and copies as it is, with the replay buffer that holds it.
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
        # Number of leaves once padded to a power of two, so that every leaf is at the same depth
        self._n_leaves = 1 << (self.capacity - 1).bit_length()
        self._depth = self._n_leaves.bit_length() - 1
        self._leaf_offset = self._n_leaves - 1
        self._sums = np.zeros(2 * self._n_leaves - 1, dtype=np.float64)
        self._mins = np.full(2 * self._n_leaves - 1, np.inf, dtype=np.float64)

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
        return float(self._sums[0])

    @property
    def min(self) -> float:
        """
        :return: the smallest positive priority; +inf if all priorities are 0
        """
        return float(self._mins[0])

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
        return self._sums[self._leaf_offset + self._check_indices(indices)]

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

    def update(self, indices: np.ndarray, priorities: np.ndarray) -> None:
        """
        Set the priorities of a batch of leaves, then recompute their ancestors in both trees.

        A priority of 0 empties its leaf: it is never drawn, and it does not count for ``min``.

        :param indices: leaf indices in ``[0, capacity)``; where one repeats, the last priority given for it wins, as
            with a loop of single updates
        :param priorities: the new priorities (already raised to the power alpha), finite and non-negative, one per
            index (or one for all)
        """
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

        # NumPy does not promise which value of a repeated index a fancy assignment keeps: keep the last explicitly.
        # np.unique returns the first occurrence of each index in the reversed arrays, the last one in the given order;
        # its indices come out sorted, which the deduplication of parents below relies on.
        leaves, last = np.unique(indices[::-1], return_index=True)
        new_priorities = priorities[::-1][last]
        nodes = leaves + self._leaf_offset
        self._sums[nodes] = new_priorities
        self._mins[nodes] = np.where(new_priorities > 0.0, new_priorities, np.inf)

        for _ in range(self._depth):
            parents = (nodes - 1) >> 1
            # Sorted nodes have sorted parents: siblings give the same parent side by side
            nodes = parents[np.concatenate(([True], parents[1:] != parents[:-1]))]
            left = 2 * nodes + 1
            self._sums[nodes] = self._sums[left] + self._sums[left + 1]
            self._mins[nodes] = np.minimum(self._mins[left], self._mins[left + 1])

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

        remaining = values.ravel().copy()
        nodes = np.zeros(remaining.shape, dtype=np.int64)
        for _ in range(self._depth):
            left = 2 * nodes + 1
            left_sums = self._sums[left]
            # Go right only into a subtree with some priority: the descent enters only nodes of positive sum (the root
            # included, as total > 0), so one of the two children is positive and when the right one is 0 the left
            # one is, and it ends on a positive leaf.
            go_right = (remaining >= left_sums) & (self._sums[left + 1] > 0.0)
            remaining = np.where(go_right, remaining - left_sums, remaining)
            nodes = left + go_right
        return (nodes - self._leaf_offset).reshape(values.shape)

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
        low = np.arange(batch_size, dtype=np.float64) * segment
        # rng.uniform may return its upper bound by rounding, and the last segment's end may round above total
        values = np.minimum(rng.uniform(low, low + segment), total)
        return self.find(values)

    def sample_proportional(self, batch_size: int, rng: np.random.Generator) -> np.ndarray:
        """
        Independent proportional sampling: each index is drawn with probability ``p_i / total``, independently of the
        others (with replacement, no strata).

        :param batch_size: the number of indices to draw
        :param rng: the random number generator
        :return: leaf indices (int64), all of positive priority
        """
        total = self._check_batch_size(batch_size)
        values = np.minimum(rng.uniform(0.0, total, size=batch_size), total)
        return self.find(values)
