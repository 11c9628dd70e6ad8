"""Checks that several test modules share (pytest puts this folder on the import path; it collects no tests here)."""

import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm


def assert_same_parameters(ours: BaseAlgorithm, reference: BaseAlgorithm) -> None:
    """Every tensor of the two policies is equal, bit for bit; a failure names the first one that differs."""
    for (name, ours_param), (_, reference_param) in zip(
        ours.policy.state_dict().items(), reference.policy.state_dict().items(), strict=True
    ):
        assert th.equal(ours_param, reference_param), name
