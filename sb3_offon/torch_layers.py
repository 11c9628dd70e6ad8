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


class DataEfficientCNN(BaseFeaturesExtractor):
    """
    The "data-efficient" network of Data-Efficient Rainbow (DER) for Atari frames, up to its output layer: a convolution
    of 32 channels, 5 x 5, stride 5; ReLU; a convolution of 64 channels, 5 x 5, stride 5; ReLU; a fully connected layer
    of 256 units; ReLU. On 84 x 84 frames the convolutions leave 64 x 3 x 3 = 576 values, against 3,136 and three
    convolutions in SB3's ``NatureCNN``: a gradient step costs about a tenth of NatureCNN's on a CPU, which is what makes
    the Atari 100k protocol (100,000 gradient steps) an affair of half an hour of one core.

    Paper: van Hasselt, Hessel & Aslanides, "When to use parametric models in reinforcement learning?", NeurIPS 2019.
    https://arxiv.org/abs/1906.05243 (Appendix: the network of Data-Efficient Rainbow; ``--architecture
    data-efficient`` of https://github.com/Kaixhin/Rainbow). Without DER's noisy, dueling and distributional heads:
    with ``net_arch=[]`` DQN's head is one linear layer from the 256 features to the actions::

        policy_kwargs=dict(features_extractor_class=DataEfficientCNN, net_arch=[])

    Observations are images as SB3 gives them to its CNN policies: channels first (``VecTransposeImage``) and, for
    ``uint8`` images, already divided by 255 by SB3's preprocessing.

    :param observation_space: a ``Box`` of shape (channels, height, width), at least 25 x 25
    :param features_dim: units of the fully connected layer (256 in DER)
    :param normalized_image: whether the images are already in [0, 1] (SB3's ``normalize_images=False`` case); only
        used in the check that the space is an image (as SB3's ``NatureCNN``)
    """

    def __init__(self, observation_space: gym.Space, features_dim: int = 256, normalized_image: bool = False) -> None:
        if not isinstance(observation_space, gym.spaces.Box) or len(observation_space.shape) != 3:
            raise ValueError(
                f"`observation_space` must be a Box of three dimensions (channels-first images), got {observation_space!r}"
            )
        channels, height, width = observation_space.shape
        if min(height, width) < 25:
            raise ValueError(
                f"`observation_space` must be images of at least 25 x 25 (two 5 x 5 convolutions of stride 5), got "
                f"{observation_space.shape}"
            )
        super().__init__(observation_space, features_dim)
        self.cnn = nn.Sequential(
            nn.Conv2d(channels, 32, kernel_size=5, stride=5),
            nn.ReLU(),
            nn.Conv2d(32, 64, kernel_size=5, stride=5),
            nn.ReLU(),
            nn.Flatten(),
        )
        with th.no_grad():
            n_flatten = self.cnn(th.zeros(1, channels, height, width)).shape[1]
        self.linear = nn.Sequential(nn.Linear(n_flatten, features_dim), nn.ReLU())

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.linear(self.cnn(observations))
