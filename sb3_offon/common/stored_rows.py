"""
Stored observations read chunk by chunk: what a refresh of the lambda-return cache passes through the target network.

A refresh computes tens of thousands of targets (64,000 with the Atari 100k settings: a refresh every 2,000 gradient
steps of 32), each bootstrapped from one stored next observation. Gathered into one array before the network's pass,
those are 64,000 x 28 KB = 1.8 GB of Atari frames, beside a replay buffer of 2.8 GB, and a temporary of that size leaves
the process larger than it needs to be. :class:`StoredRows` holds only where the rows are (slot and env column of each),
and gathers the rows a chunk of the network's pass asks for into an array it reuses from chunk to chunk: the memory of
a refresh is bounded by its chunks, not by the number of targets it computes.
"""

from collections.abc import Callable
from typing import Any

import numpy as np


class StoredRows:
    """
    The rows ``source[slots[i], envs[i]]`` of a replay buffer's observations (an array shaped (buffer_size, n_envs,
    ...), or a dict of them), normalised by ``normalize``, read by slices of ``i``: ``rows[start:stop]``.

    A slice is gathered into an array that the next read overwrites (one per key, grown to the largest slice read):
    use it before reading again, as a chunked pass through a network does. :meth:`array` gives every row in an array of
    its own.

    :param source: the buffer's observations (``observations`` with ``optimize_memory_usage``, else
        ``next_observations``)
    :param slots: the rows' slots
    :param envs: their env columns
    :param normalize: what the buffer's ``sample()`` applies to observations (VecNormalize's normalisation, or nothing)
    """

    def __init__(
        self,
        source: np.ndarray | dict[str, np.ndarray],
        slots: np.ndarray,
        envs: np.ndarray,
        normalize: Callable[[Any], Any],
    ) -> None:
        if len(slots) != len(envs):
            raise ValueError(f"`slots` and `envs` must have the same length, got {len(slots)} and {len(envs)}")
        self.source = source
        self.slots = np.asarray(slots)
        self.envs = np.asarray(envs)
        self.normalize = normalize
        self._reused: dict[str | None, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.slots)

    def __getitem__(self, rows: slice) -> Any:
        """The rows of ``rows`` (a slice), in the array reused from read to read (a dict of them for Dict observations)."""
        if not isinstance(rows, slice):
            raise TypeError(f"StoredRows are read by slices, got {type(rows).__name__}")
        slots, envs = self.slots[rows], self.envs[rows]
        if isinstance(self.source, dict):
            return self.normalize({key: self._gather(value, slots, envs, key) for key, value in self.source.items()})
        return self.normalize(self._gather(self.source, slots, envs, None))

    def array(self) -> Any:
        """Every row, in an array of its own (a dict of them for Dict observations), normalised."""
        if isinstance(self.source, dict):
            return self.normalize({key: value[self.slots, self.envs] for key, value in self.source.items()})
        return self.normalize(self.source[self.slots, self.envs])

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        array = self.array()
        if isinstance(array, dict):
            raise TypeError("StoredRows of Dict observations are not one array: read them by slices or with array()")
        return np.asarray(array, dtype=dtype)

    def _gather(self, source: np.ndarray, slots: np.ndarray, envs: np.ndarray, key: str | None) -> np.ndarray:
        """``source[slots, envs]`` into the reused array of ``key`` (``np.take`` on the buffer's flat view: no copy of it)."""
        if not source.flags.c_contiguous:  # a flat view would be a copy of the whole buffer: index it as it is
            return source[slots, envs]
        n_envs = source.shape[1]
        flat = source.reshape(-1, *source.shape[2:])
        reused = self._reused.get(key)
        if reused is None or len(reused) < len(slots):
            reused = self._reused[key] = np.empty((len(slots), *source.shape[2:]), dtype=source.dtype)
        out = reused[: len(slots)]
        np.take(flat, slots * n_envs + envs, axis=0, out=out)
        return out
