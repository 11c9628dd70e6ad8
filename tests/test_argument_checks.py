"""The off-policy arguments that SB3 takes unchecked: a ``ValueError`` naming the parameter at construction, for
OffOnDQN, OffOnQRDQN and the package's QRDQN (and on load, where ``_setup_model`` runs again)."""

import pytest

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.qrdqn import QRDQN

ALGORITHMS = [OffOnDQN, OffOnQRDQN, QRDQN]
SMALL = dict(buffer_size=100, learning_starts=0, policy_kwargs=dict(net_arch=[8]))

BAD = [
    ("batch_size", 0),
    ("batch_size", -3),
    ("batch_size", 2.0),
    ("n_steps", 0),
    ("train_freq", 0),
    ("train_freq", (0, "step")),
    ("train_freq", (0, "episode")),  # SB3 checks the type and unit only
    ("gradient_steps", -2),
    ("gradient_steps", 1.0),
    ("target_update_interval", 0),
    ("learning_starts", -1),
    ("lambda_block_size", 0),
]


@pytest.mark.parametrize("algorithm", ALGORITHMS)
@pytest.mark.parametrize(("name", "value"), BAD)
def test_a_bad_argument_is_a_value_error_naming_it(algorithm: type, name: str, value: object) -> None:
    if name == "lambda_block_size" and algorithm is QRDQN:
        pytest.skip("QR-DQN has no lambda-returns")
    arguments = {**SMALL, name: value}
    with pytest.raises(ValueError, match=f"`{name}`"):
        algorithm("MlpPolicy", "CartPole-v1", **arguments)


GOOD = [
    ("gradient_steps", -1),  # SB3's: as many gradient steps as env steps in the rollout
    ("gradient_steps", 0),  # SB3's special case: no training
    ("train_freq", (2, "episode")),
    ("learning_starts", 0),
    ("n_steps", 3),
]


@pytest.mark.parametrize("algorithm", ALGORITHMS)
@pytest.mark.parametrize(("name", "value"), GOOD)
def test_what_sb3_allows_is_allowed_and_trains(algorithm: type, name: str, value: object) -> None:
    model = algorithm("MlpPolicy", "CartPole-v1", batch_size=8, **{**SMALL, name: value})
    model.learn(40)
    assert model.num_timesteps >= 40  # whole episodes with an episode frequency


@pytest.mark.parametrize("algorithm", [OffOnDQN, OffOnQRDQN])
def test_checked_again_when_load_changes_them(algorithm: type, tmp_path) -> None:
    """``load``'s keyword arguments reach the model without ``__init__``: ``_setup_model`` checks them."""
    algorithm("MlpPolicy", "CartPole-v1", **SMALL).save(tmp_path / "model")
    with pytest.raises(ValueError, match="`batch_size`"):
        algorithm.load(tmp_path / "model", batch_size=0)
