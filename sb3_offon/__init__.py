"""sb3-offon: the Offline-Online DQN of Kim (Symmetry 2020) as a drop-in Stable-Baselines3 algorithm."""

from sb3_offon.common.buffers import (
    OffOnDictReplayBuffer,
    OffOnDictReplayBufferSamples,
    OffOnNStepReplayBuffer,
    OffOnReplayBuffer,
    OffOnReplayBufferSamples,
)
from sb3_offon.offon_dqn import CnnPolicy, MlpPolicy, MultiInputPolicy, OffOnDQN

__version__ = "0.1.0"

__all__ = [
    "CnnPolicy",
    "MlpPolicy",
    "MultiInputPolicy",
    "OffOnDQN",
    "OffOnDictReplayBuffer",
    "OffOnDictReplayBufferSamples",
    "OffOnNStepReplayBuffer",
    "OffOnReplayBuffer",
    "OffOnReplayBufferSamples",
]
