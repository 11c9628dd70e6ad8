"""sb3-offon: the Offline-Online DQN of Kim (Symmetry 2020) as a drop-in Stable-Baselines3 algorithm."""

from pathlib import Path

from sb3_offon import (
    atari,  # noqa: F401  (registers the ALE's ids when ale-py is installed)
    envs,  # noqa: F401  (registers CartPoleFallPenalty-v1 and MountainCarGoalBonus-v0)
    minatar_envs,  # noqa: F401  (registers the MinAtar/* ids)
)
from sb3_offon.common.buffers import (
    OffOnDictReplayBuffer,
    OffOnDictReplayBufferSamples,
    OffOnNStepReplayBuffer,
    OffOnReplayBuffer,
    OffOnReplayBufferSamples,
)
from sb3_offon.common.lambda_horizons import lambda_for_horizon
from sb3_offon.common.prioritized_buffers import (
    PrioritizedOffOnDictReplayBuffer,
    PrioritizedOffOnNStepReplayBuffer,
    PrioritizedOffOnReplayBuffer,
)
from sb3_offon.offon_dqn import CnnPolicy, MlpPolicy, MultiInputPolicy, OffOnDQN
from sb3_offon.offon_qrdqn import OffOnQRDQN
from sb3_offon.presets import LAMBDA_CHOICE_TARGETS, PAPER_TARGETS
from sb3_offon.torch_layers import DataEfficientCNN, MinAtarCNN
from sb3_offon.variants import DQNMC, DQNSarsa

# The version is written once, in version.txt (read by setuptools too, see pyproject.toml)
__version__ = (Path(__file__).parent / "version.txt").read_text(encoding="utf-8").strip()

__all__ = [
    "DQNMC",
    "LAMBDA_CHOICE_TARGETS",
    "PAPER_TARGETS",
    "CnnPolicy",
    "DQNSarsa",
    "DataEfficientCNN",
    "MinAtarCNN",
    "MlpPolicy",
    "MultiInputPolicy",
    "OffOnDQN",
    "OffOnDictReplayBuffer",
    "OffOnDictReplayBufferSamples",
    "OffOnNStepReplayBuffer",
    "OffOnQRDQN",
    "OffOnReplayBuffer",
    "OffOnReplayBufferSamples",
    "PrioritizedOffOnDictReplayBuffer",
    "PrioritizedOffOnNStepReplayBuffer",
    "PrioritizedOffOnReplayBuffer",
    "lambda_for_horizon",
]
