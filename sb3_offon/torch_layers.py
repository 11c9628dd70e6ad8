"""Features extractors for SB3 policies."""

import gymnasium as gym
import torch as th
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn


class MinAtarCNN(BaseFeaturesExtractor):
    """
    The network of the MinAtar paper's DQN, up to its output layer: one 3 x 3 convolution of 16 channels (stride 1, no
    padding), ReLU, a fully connected layer of 128 units, ReLU.

    Paper: Young & Tian, "MinAtar: An Atari-Inspired Testbed for Thorough and Reproducible Reinforcement Learning
    Experiments", 2019. https://arxiv.org/abs/1903.03176 (``examples/dqn.py`` of https://github.com/kenjyoung/MinAtar)

    SB3's ``NatureCNN`` needs images of at least 36 x 36 pixels; MinAtar's are 10 x 10 x C grids of booleans, channels
    last. They reach this extractor as floats (SB3's preprocessing casts a ``Box`` observation to float and does not
    divide it by 255, which only images of ``uint8`` get) and are moved to channels first here. The algorithm's head
    follows: with ``net_arch=[]``, DQN's is one linear layer from the 128 features to the actions, as in the paper::

        policy_kwargs=dict(features_extractor_class=MinAtarCNN, net_arch=[])

    :param observation_space: a ``Box`` of shape (height, width, channels), or (channels, height, width) with
        ``channels_last=False``
    :param features_dim: units of the fully connected layer (128 in the paper)
    :param channels_last: whether the channels are the last axis of an observation (MinAtar's layout)
    """

    def __init__(self, observation_space: gym.Space, features_dim: int = 128, channels_last: bool = True) -> None:
        if not isinstance(observation_space, gym.spaces.Box) or len(observation_space.shape) != 3:
            raise ValueError(
                f"`observation_space` must be a Box of three dimensions (a MinAtar grid), got {observation_space!r}"
            )
        super().__init__(observation_space, features_dim)
        self.channels_last = channels_last
        shape = observation_space.shape
        height, width, channels = shape if channels_last else (shape[1], shape[2], shape[0])
        if min(height, width) < 3:
            raise ValueError(f"`observation_space` must be at least 3 x 3 for a 3 x 3 convolution, got {shape}")
        self.cnn = nn.Sequential(nn.Conv2d(channels, 16, kernel_size=3, stride=1), nn.ReLU(), nn.Flatten())
        self.linear = nn.Sequential(nn.Linear(16 * (height - 2) * (width - 2), features_dim), nn.ReLU())

    def forward(self, observations: th.Tensor) -> th.Tensor:
        if self.channels_last:
            observations = observations.permute(0, 3, 1, 2)
        return self.linear(self.cnn(observations.float()))
