"""
The paper's two ablations of Offline-Online DQN, as OffOnDQN with other defaults (no code of their own).

With SB3's own DQN and OffOnDQN they make the paper's four variants:

=============  =====================================  ==========================================
Algorithm      delta1 = P(Monte-Carlo target)         delta2 = P(Q-learning given a TD target)
=============  =====================================  ==========================================
``DQN``        0 (SB3's DQN)                          1
``DQNSarsa``   0                                      0.99 -> 0.01 (Sarsa grows)
``DQNMC``      0.99 -> 0.01                           1
``OffOnDQN``   0.99 -> 0.01                           0.99 -> 0.01
=============  =====================================  ==========================================

Every OffOnDQN argument is accepted and can still be set, the probabilities included. ``load()`` restores the
saved values, whatever these defaults are.
"""

from typing import Any

from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.dqn.policies import DQNPolicy

from sb3_offon.offon_dqn import OffOnDQN


class DQNMC(OffOnDQN):
    """
    DQN with Monte-Carlo targets ("DQN with MC" in the paper): OffOnDQN whose TD targets are always Q-learning
    (delta2 fixed at 1, no Sarsa); delta1 decays from 0.99 to 0.01 as in OffOnDQN.

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, ...)
    :param env: The environment to learn from (if registered in Gym, can be str)
    :param qlearning_initial_prob: initial delta2 (1: Q-learning only)
    :param qlearning_final_prob: final delta2 (1: Q-learning only)
    :param kwargs: any other argument of :class:`sb3_offon.OffOnDQN`, by keyword
    """

    def __init__(
        self,
        policy: str | type[DQNPolicy],
        env: GymEnv | str,
        *,
        qlearning_initial_prob: float = 1.0,
        qlearning_final_prob: float = 1.0,
        **kwargs: Any,
    ) -> None:
        super().__init__(
            policy,
            env,
            qlearning_initial_prob=qlearning_initial_prob,
            qlearning_final_prob=qlearning_final_prob,
            **kwargs,
        )


class DQNSarsa(OffOnDQN):
    """
    DQN with Sarsa ("DQN with Sarsa" in the paper): OffOnDQN without Monte-Carlo targets (delta1 fixed at 0);
    delta2 decays from 0.99 to 0.01 as in OffOnDQN, so the TD targets move from Q-learning to Sarsa.

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, ...)
    :param env: The environment to learn from (if registered in Gym, can be str)
    :param mc_initial_prob: initial delta1 (0: no Monte-Carlo target)
    :param mc_final_prob: final delta1 (0: no Monte-Carlo target)
    :param kwargs: any other argument of :class:`sb3_offon.OffOnDQN`, by keyword
    """

    def __init__(
        self,
        policy: str | type[DQNPolicy],
        env: GymEnv | str,
        *,
        mc_initial_prob: float = 0.0,
        mc_final_prob: float = 0.0,
        **kwargs: Any,
    ) -> None:
        super().__init__(
            policy,
            env,
            mc_initial_prob=mc_initial_prob,
            mc_final_prob=mc_final_prob,
            **kwargs,
        )
