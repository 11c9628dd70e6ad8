"""The Off-On arguments that OffOnDQN and OffOnQRDQN share live once (:mod:`sb3_offon.common.offon_arguments`): both
state them with the same defaults, reject the same bad value with the same ``ValueError``, set them as attributes and
save them alike, and leave the same attributes out of saved files."""

import inspect
from pathlib import Path

import pytest
from stable_baselines3 import DQN
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.common.offon_arguments import OFFON_PARAMETERS, OffOnArgumentsMixin
from sb3_offon.qrdqn import QRDQN

CLASSES = [(OffOnDQN, DQN), (OffOnQRDQN, QRDQN)]
SMALL = dict(buffer_size=100, learning_starts=0, policy_kwargs=dict(net_arch=[8]))
SHARED = OffOnArgumentsMixin.offon_parameters

# One bad value of each shared argument, each with the start of its message
BAD = [
    ("mc_initial_prob", 1.5, "`mc_initial_prob` must be a probability in [0, 1]"),
    ("mc_final_prob", "0.5", "`mc_final_prob` must be a real number"),
    ("mc_fraction", 0.0, "`mc_fraction` must be in (0, 1]"),
    ("qlearning_initial_prob", -0.1, "`qlearning_initial_prob` must be a probability in [0, 1]"),
    ("qlearning_final_prob", float("nan"), "`qlearning_final_prob` must be a real number"),
    ("qlearning_fraction", 1.2, "`qlearning_fraction` must be in (0, 1]"),
    ("mc_truncation", "ignore", "`mc_truncation` must be one of"),
    ("lambda_block_size", 0, "`lambda_block_size` must be a positive integer"),
    ("lambda_refresh_interval", 0, "`lambda_refresh_interval` must be a positive integer or None"),
    ("lambda_choice", "mean", "`lambda_choice` must be one of"),
    ("lambda_horizon", 0.5, "`lambda_horizon` must be a finite number of env steps"),
    ("double_q", 1, "`double_q` must be True or False"),
    ("non_finite", "ignore", "`non_finite` must be one of"),
]


def error_message(algorithm: type, **arguments: object) -> str:
    with pytest.raises(ValueError) as error:
        algorithm("MlpPolicy", "CartPole-v1", **SMALL, **arguments)
    return str(error.value)


def test_the_shared_arguments_are_every_class_s_with_the_same_defaults() -> None:
    assert SHARED == (*OFFON_PARAMETERS, "non_finite")
    dqn, qrdqn = (inspect.signature(algorithm).parameters for algorithm, _ in CLASSES)
    for name in SHARED:
        assert dqn[name].default == qrdqn[name].default, name
        for algorithm, _ in CLASSES:
            assert f":param {name}:" in (algorithm.__doc__ or ""), (algorithm.__name__, name)
    # What OffOnQRDQN adds is its own, and set as attributes too
    assert set(OffOnQRDQN.offon_parameters) - set(SHARED) == {"lambda_form", "lambda_cache"}


@pytest.mark.parametrize(("name", "value", "message"), BAD)
def test_a_bad_shared_argument_is_the_same_value_error_in_both(name: str, value: object, message: str) -> None:
    dqn_message, qrdqn_message = (error_message(algorithm, **{name: value}) for algorithm, _ in CLASSES)
    assert dqn_message == qrdqn_message
    assert dqn_message.startswith(message)


@pytest.mark.parametrize(("name", "value", "message"), BAD[:3])
def test_a_bad_shared_argument_given_to_load_is_the_same_value_error_in_both(
    name: str, value: object, message: str, tmp_path: Path
) -> None:
    messages = []
    for algorithm, _ in CLASSES:
        path = tmp_path / algorithm.__name__
        algorithm("MlpPolicy", "CartPole-v1", **SMALL).save(path)
        with pytest.raises(ValueError) as error:
            algorithm.load(path, **{name: value})
        messages.append(str(error.value))
    assert messages[0] == messages[1]
    assert messages[0].startswith(message)


def test_both_save_the_shared_arguments_and_leave_out_the_same_attributes(tmp_path: Path) -> None:
    added_exclusions = []
    for algorithm, base in CLASSES:
        arguments = dict(mc_initial_prob=0.25, lambda_block_size=7, lambda_refresh_interval=50, non_finite="skip")
        model = algorithm("MlpPolicy", "CartPole-v1", **SMALL, **arguments)
        for name in SHARED:
            assert hasattr(model, name), (algorithm.__name__, name)
        # What the Off-On class leaves out beyond its algorithm's own
        base_model = base("MlpPolicy", "CartPole-v1", **SMALL)
        added = set(model._excluded_save_params()) - set(base_model._excluded_save_params())
        added_exclusions.append(added)
        model.save(tmp_path / algorithm.__name__)
        data, _, _ = load_from_zip_file(tmp_path / algorithm.__name__)
        assert data is not None
        assert set(SHARED) <= set(data), algorithm.__name__
        assert not added & set(data), algorithm.__name__
        loaded = algorithm.load(tmp_path / algorithm.__name__)
        for name, value in arguments.items():
            assert getattr(loaded, name) == value, (algorithm.__name__, name)
    assert added_exclusions[0] == added_exclusions[1] == {"mc_schedule", "qlearning_schedule", "_lambda_cache"}


def test_a_constructor_that_passes_on_too_few_arguments_is_a_type_error() -> None:
    class Forgetful(OffOnDQN):
        def __init__(self, policy: str, env: str) -> None:
            OffOnArgumentsMixin.__init__(self, policy=policy, env=env, _init_setup_model=False)

    with pytest.raises(TypeError, match="mc_initial_prob"):
        Forgetful("MlpPolicy", "CartPole-v1")
