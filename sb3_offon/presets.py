"""
Named sets of :class:`sb3_offon.OffOnDQN` target arguments.

``OffOnDQN("MlpPolicy", env)`` trains on lambda-returns (the defaults since the second head-to-head, seeds 20-29);
the paper's Offline-Online DQN, with its coin-flip targets, is ``OffOnDQN("MlpPolicy", env, **PAPER_TARGETS)``, as
``--algo offon_paper`` is on the command line. To change one of a preset's values, merge it:
``OffOnDQN("MlpPolicy", env, **{**PAPER_TARGETS, "mc_final_prob": 0.1})`` (a key passed twice is a ``TypeError``).
The presets are read-only mappings, so that no caller can change them for the others.
"""

from types import MappingProxyType
from typing import Any

# Kim (Symmetry 2020), Section 4: delta1 = P(Monte-Carlo target) and delta2 = P(Q-learning | TD target), both decaying
# linearly from 0.99 to 0.01 over training, one target drawn per sample: OffOnDQN's defaults in version 0.1.0. Its
# other arguments keep their defaults (mc_truncation="bootstrap", the Huber loss: see hyperparams/paper/ for the paper's
# MSE and terminal time limits).
PAPER_TARGETS: MappingProxyType[str, Any] = MappingProxyType(
    {
        "mc_mixing": "sample",
        "mc_initial_prob": 0.99,
        "mc_final_prob": 0.01,
        "mc_fraction": 1.0,
        "qlearning_initial_prob": 0.99,
        "qlearning_final_prob": 0.01,
        "qlearning_fraction": 1.0,
    }
)

# OffOnDQN's defaults since the second head-to-head (seeds 20-29, results/headtohead2/README.md): lambda-returns with
# lambda = 0.9 throughout and Peng's Q(lambda) (delta2 = 0)
LAMBDA_CHOICE_TARGETS: MappingProxyType[str, Any] = MappingProxyType(
    {
        "mc_mixing": "lambda",
        "mc_initial_prob": 0.9,
        "mc_final_prob": 0.9,
        "mc_fraction": 1.0,
        "qlearning_initial_prob": 0.0,
        "qlearning_final_prob": 0.0,
        "qlearning_fraction": 1.0,
    }
)
