"""sb3-offon: the Offline-Online DQN of Kim (Symmetry 2020) as a drop-in Stable-Baselines3 algorithm."""

from sb3_offon import envs  # noqa: F401  (registers CartPoleFallPenalty-v1 and MountainCarGoalBonus-v0)
from sb3_offon.common.buffers import (
    OffOnDictReplayBuffer,
    OffOnDictReplayBufferSamples,
    OffOnNStepReplayBuffer,
    OffOnReplayBuffer,
    OffOnReplayBufferSamples,
)
from sb3_offon.offon_dqn import CnnPolicy, MlpPolicy, MultiInputPolicy, OffOnDQN
from sb3_offon.variants import DQNMC, DQNSarsa

__version__ = "0.1.0"

__all__ = [
    "DQNMC",
    "CnnPolicy",
    "DQNSarsa",
    "MlpPolicy",
    "MultiInputPolicy",
    "OffOnDQN",
    "OffOnDictReplayBuffer",
    "OffOnDictReplayBufferSamples",
    "OffOnNStepReplayBuffer",
    "OffOnReplayBuffer",
    "OffOnReplayBufferSamples",
]
