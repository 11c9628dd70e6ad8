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

(``OffOnDQN`` in that table is ``OffOnDQN(policy, env, **PAPER_TARGETS)``: its defaults are lambda-returns since
the second head-to-head, ``results/headtohead2/README.md``.) DQNMC and DQNSarsa draw one target per sample, as in the
paper (``mc_mixing="sample"``), whatever OffOnDQN's defaults are.

Every OffOnDQN argument is accepted and can still be set, the probabilities included. ``load()`` restores the
saved values, whatever these defaults are.
"""

from typing import Any

from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.dqn.policies import DQNPolicy

from sb3_offon.offon_dqn import OffOnDQN
from sb3_offon.presets import PAPER_TARGETS


class DQNMC(OffOnDQN):
    """
    DQN with Monte-Carlo targets ("DQN with MC" in the paper): OffOnDQN whose TD targets are always Q-learning
    (delta2 fixed at 1, no Sarsa); delta1 decays from 0.99 to 0.01 as in OffOnDQN.

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, ...)
    :param env: The environment to learn from (if registered in Gym, can be str)
    :param mc_initial_prob: initial delta1 (the paper's 0.99)
    :param mc_final_prob: final delta1 (the paper's 0.01)
    :param qlearning_initial_prob: initial delta2 (1: Q-learning only)
    :param qlearning_final_prob: final delta2 (1: Q-learning only)
    :param mc_mixing: how the Monte-Carlo target enters (``"sample"``: drawn with probability delta1, the paper's)
    :param kwargs: any other argument of :class:`sb3_offon.OffOnDQN`, by keyword
    """

    def __init__(
        self,
        policy: str | type[DQNPolicy],
        env: GymEnv | str,
        *,
        mc_initial_prob: float = PAPER_TARGETS["mc_initial_prob"],
        mc_final_prob: float = PAPER_TARGETS["mc_final_prob"],
        qlearning_initial_prob: float = 1.0,
        qlearning_final_prob: float = 1.0,
        mc_mixing: str = PAPER_TARGETS["mc_mixing"],
        **kwargs: Any,
    ) -> None:
        super().__init__(
            policy,
            env,
            mc_initial_prob=mc_initial_prob,
            mc_final_prob=mc_final_prob,
            qlearning_initial_prob=qlearning_initial_prob,
            qlearning_final_prob=qlearning_final_prob,
            mc_mixing=mc_mixing,
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
    :param qlearning_initial_prob: initial delta2 (the paper's 0.99)
    :param qlearning_final_prob: final delta2 (the paper's 0.01)
    :param mc_mixing: how the Monte-Carlo target enters (``"sample"``, the paper's; with delta1 = 0 it never does)
    :param kwargs: any other argument of :class:`sb3_offon.OffOnDQN`, by keyword
    """

    def __init__(
        self,
        policy: str | type[DQNPolicy],
        env: GymEnv | str,
        *,
        mc_initial_prob: float = 0.0,
        mc_final_prob: float = 0.0,
        qlearning_initial_prob: float = PAPER_TARGETS["qlearning_initial_prob"],
        qlearning_final_prob: float = PAPER_TARGETS["qlearning_final_prob"],
        mc_mixing: str = PAPER_TARGETS["mc_mixing"],
        **kwargs: Any,
    ) -> None:
        super().__init__(
            policy,
            env,
            mc_initial_prob=mc_initial_prob,
            mc_final_prob=mc_final_prob,
            qlearning_initial_prob=qlearning_initial_prob,
            qlearning_final_prob=qlearning_final_prob,
            mc_mixing=mc_mixing,
            **kwargs,
        )
