"""
How OffOnDQN's two trainings (the coin-flip targets and the lambda-returns) gather their minibatches: several gradient
steps' samples at once, in chunks small enough for the device, uploaded once and read by rows.
"""

import math
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces

# At most this many bytes of observations (and as much for next observations) are gathered and uploaded at once
MAX_CHUNK_BYTES = 64 * 2**20


class ChunkedMinibatchesMixin:
    """The chunk size and the uploads of :class:`sb3_offon.OffOnDQN`'s training calls."""

    # Attributes of SB3's DQN, declared for type checkers
    observation_space: spaces.Space
    device: th.device

    def _steps_per_chunk(self, batch_size: int) -> int:
        """
        How many minibatches to gather, upload and run through the target network at once: all of a call's, unless
        their observations and next observations, as float32 in the networks, would take more than
        ``MAX_CHUNK_BYTES`` (1,000 gradient steps on Atari frames would be some 7 GB).
        """
        sample_bytes = 2 * self._observation_bytes()
        return max(1, MAX_CHUNK_BYTES // (batch_size * max(sample_bytes, 1)))

    def _observation_bytes(self) -> int:
        """The bytes of one observation as float32 in the networks (every key of a Dict observation)."""
        observation_spaces: list[spaces.Space] = (
            list(self.observation_space.spaces.values())
            if isinstance(self.observation_space, spaces.Dict)
            else [self.observation_space]
        )
        return 4 * sum(math.prod(space.shape or (1,)) for space in observation_spaces)

    def _to_device(self, array: np.ndarray) -> th.Tensor:
        # from_numpy then to(): a few times cheaper than as_tensor(..., device=...) for a small array on the CPU
        return th.from_numpy(array).to(self.device)


def rows_of(value: Any, rows: slice) -> Any:
    """The rows of a tensor, array, dict of them or samples NamedTuple (views, not copies); None stays None."""
    if value is None:
        return None
    if isinstance(value, tuple):
        return type(value)(*(rows_of(item, rows) for item in value))
    if isinstance(value, dict):
        return {key: item[rows] for key, item in value.items()}
    return value[rows]
