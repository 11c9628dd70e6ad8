"""
OffOnDQN's policies: SB3's DQN policies, with dueling networks as an option (``policy_kwargs=dict(dueling=True)``).

With ``dueling=False``, the default, a policy builds exactly SB3's ``QNetwork`` (same modules, same parameters, drawn
in the same order): OffOnDQN learns the same Q-network as DQN, and only the regression targets differ.
"""

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import (
    BaseFeaturesExtractor,
    CombinedExtractor,
    FlattenExtractor,
    NatureCNN,
    create_mlp,
)
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.dqn.policies import DQNPolicy, QNetwork
from torch import nn


class DuelingHead(nn.Module):
    """
    Q(s, a) = V(s) + A(s, a) - mean_a' A(s, a') from the features of s: a value stream and an advantage stream, each an
    MLP with the hidden layers ``net_arch``.

    Paper: Wang et al., "Dueling Network Architectures for Deep Reinforcement Learning", ICML 2016.
    https://arxiv.org/abs/1511.06581 (equation 9: the mean advantage is subtracted, which keeps V and A identifiable)

    :param features_dim: size of the features
    :param n_actions: number of actions
    :param net_arch: hidden layers of each stream
    :param activation_fn: activation after each hidden layer
    """

    def __init__(self, features_dim: int, n_actions: int, net_arch: list[int], activation_fn: type[nn.Module]) -> None:
        super().__init__()
        self.value_stream = nn.Sequential(*create_mlp(features_dim, 1, net_arch, activation_fn))
        self.advantage_stream = nn.Sequential(*create_mlp(features_dim, n_actions, net_arch, activation_fn))

    def forward(self, features: th.Tensor) -> th.Tensor:
        advantages = self.advantage_stream(features)
        return self.value_stream(features) + advantages - advantages.mean(dim=1, keepdim=True)


class DuelingQNetwork(QNetwork):
    """
    SB3's ``QNetwork`` whose head (``q_net``) is a :class:`DuelingHead`; the features extractor is unchanged.

    :param observation_space: Observation space
    :param action_space: Action space
    :param features_extractor: the features extractor (shared by both streams)
    :param features_dim: size of its features
    :param net_arch: hidden layers of each stream
    :param activation_fn: Activation function
    :param normalize_images: Whether to normalize images or not, dividing by 255.0 (True by default)
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        features_extractor: BaseFeaturesExtractor,
        features_dim: int,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        normalize_images: bool = True,
    ) -> None:
        super().__init__(
            observation_space, action_space, features_extractor, features_dim, net_arch, activation_fn, normalize_images
        )
        # Replaces the single stream that QNetwork builds; forward() and _predict() read q_net as they do in SB3
        self.q_net = DuelingHead(  # type: ignore[assignment]
            self.features_dim, int(self.action_space.n), self.net_arch, self.activation_fn
        )


class OffOnDQNPolicy(DQNPolicy):
    """
    SB3's ``DQNPolicy`` (the online and target Q-networks, the optimizer) with dueling networks as an option.

    :param observation_space: Observation space
    :param action_space: Action space
    :param lr_schedule: Learning rate schedule (could be constant)
    :param net_arch: The hidden layers after the features extractor (of each stream, with ``dueling=True``)
    :param activation_fn: Activation function
    :param features_extractor_class: Features extractor to use.
    :param features_extractor_kwargs: Keyword arguments to pass to the features extractor.
    :param normalize_images: Whether to normalize images or not, dividing by 255.0 (True by default)
    :param optimizer_class: The optimizer to use, ``th.optim.Adam`` by default
    :param optimizer_kwargs: Additional keyword arguments, excluding the learning rate, to pass to the optimizer
    :param dueling: a value stream and an advantage stream after the features extractor (:class:`DuelingHead`), in
        the online and the target network; False (default): SB3's single stream. A dueling head has the parameters of
        two streams: about twice the head's compute per forward pass
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        dueling: bool = False,
    ) -> None:
        if not isinstance(dueling, (bool, np.bool_)):  # (NumPy's bools, as double_q takes them)
            raise ValueError(f"`dueling` must be True or False, got {dueling!r}")
        # Set before DQNPolicy's constructor, which builds the networks through make_q_net
        self.dueling = bool(dueling)
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch,
            activation_fn,
            features_extractor_class,
            features_extractor_kwargs,
            normalize_images,
            optimizer_class,
            optimizer_kwargs,
        )

    def make_q_net(self) -> QNetwork:
        if not self.dueling:
            return super().make_q_net()
        # As DQNPolicy.make_q_net: each network gets a features extractor of its own
        net_args = self._update_features_extractor(self.net_args, features_extractor=None)
        return DuelingQNetwork(**net_args).to(self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "dueling": self.dueling}

    def set_training_mode(self, mode: bool) -> None:
        """
        Put the online network in training or evaluation mode, as SB3's ``DQNPolicy`` does (the target network stays
        in evaluation mode).

        SB3 calls this at every env step (``predict``) and every training call; ``Module.train`` walks the module tree
        each time, about 70 us for a small CNN on one CPU thread, a few percent of an env step. The online network's
        modules are listed once (per network object) and their flags written into their ``__dict__``, which is where
        ``Module.train`` puts them when no module overrides it (``nn.Module.__setattr__`` would first look the name up
        among parameters, buffers and submodules: 18 us for the ten modules of the MinAtar network, against 1 us); a
        network with a module that overrides ``train`` takes SB3's way.

        :param mode: True for training mode, False for evaluation mode
        """
        modules = self._plain_modules()
        if modules is None:
            super().set_training_mode(mode)
            return
        for module in modules:
            module.__dict__["training"] = mode
        self.training = mode

    def _plain_modules(self) -> list[nn.Module] | None:
        """The online network's modules (itself included), or None if one of them overrides ``train``."""
        cached = self.__dict__.get("_modules_of_q_net")
        if cached is None or cached[0] is not self.q_net:
            modules = list(self.q_net.modules())
            plain = all(type(module).train is nn.Module.train for module in modules)
            # In __dict__ directly: a cache, not a submodule for nn.Module to register
            cached = self.__dict__["_modules_of_q_net"] = (self.q_net, modules if plain else None)
        return cached[1]

    def parameter_list(self) -> list[nn.Parameter]:
        """
        ``list(self.parameters())``, listed once per pair of networks: the parameters whose gradients OffOnDQN clips
        after each gradient step (walking the module tree for them at each training call costs as much as the clip).
        """
        cached = self.__dict__.get("_parameter_list")
        if cached is None or cached[0] is not self.q_net or cached[1] is not self.q_net_target:
            cached = self.__dict__["_parameter_list"] = (self.q_net, self.q_net_target, list(self.parameters()))
        return cached[2]


MlpPolicy = OffOnDQNPolicy


class CnnPolicy(OffOnDQNPolicy):
    """
    :class:`OffOnDQNPolicy` for images, with SB3's ``NatureCNN`` as default features extractor (as SB3's DQN
    ``CnnPolicy``). The parameters are :class:`OffOnDQNPolicy`'s.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        features_extractor_class: type[BaseFeaturesExtractor] = NatureCNN,
        features_extractor_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        dueling: bool = False,
    ) -> None:
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch,
            activation_fn,
            features_extractor_class,
            features_extractor_kwargs,
            normalize_images,
            optimizer_class,
            optimizer_kwargs,
            dueling,
        )


class MultiInputPolicy(OffOnDQNPolicy):
    """
    :class:`OffOnDQNPolicy` for dict observations, with SB3's ``CombinedExtractor`` as default features extractor (as
    SB3's DQN ``MultiInputPolicy``). The parameters are :class:`OffOnDQNPolicy`'s.
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        features_extractor_class: type[BaseFeaturesExtractor] = CombinedExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        dueling: bool = False,
    ) -> None:
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch,
            activation_fn,
            features_extractor_class,
            features_extractor_kwargs,
            normalize_images,
            optimizer_class,
            optimizer_kwargs,
            dueling,
        )


__all__ = [
    "CnnPolicy",
    "DQNPolicy",
    "DuelingHead",
    "DuelingQNetwork",
    "MlpPolicy",
    "MultiInputPolicy",
    "OffOnDQNPolicy",
    "QNetwork",
]
