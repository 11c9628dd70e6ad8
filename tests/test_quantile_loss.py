"""The quantile Huber loss from sorted targets and sb3_offon's QR-DQN against sb3-contrib's: same values and training."""

import copy

import numpy as np
import pytest
import sb3_contrib
import torch as th
from sb3_contrib.common.utils import quantile_huber_loss as sb3_contrib_loss
from sb3_contrib.qrdqn import qrdqn as sb3_contrib_qrdqn

from sb3_offon.common.quantile_loss import quantile_huber_loss
from sb3_offon.qrdqn import QRDQN
from sb3_offon.zoo import ALGOS, register


def loss_and_gradient(loss_fn, current: th.Tensor, target: th.Tensor, **kwargs) -> tuple[th.Tensor, th.Tensor]:
    current = current.clone().requires_grad_(True)
    loss = loss_fn(current, target, **kwargs)
    loss.backward()
    return loss.detach(), current.grad


@pytest.mark.parametrize("dtype", [th.float32, th.float64])
@pytest.mark.parametrize("scale", [0.3, 2.0, 50.0])  # most pairs within the Huber threshold, some, nearly none
@pytest.mark.parametrize("batch_size, n_quantiles, n_target_quantiles", [(32, 200, 200), (5, 7, 11), (1, 1, 3)])
def test_loss_is_sb3_contribs(
    dtype: th.dtype, scale: float, batch_size: int, n_quantiles: int, n_target_quantiles: int
) -> None:
    generator = th.Generator().manual_seed(batch_size * n_quantiles)
    current = (th.randn(batch_size, n_quantiles, generator=generator) * scale).to(dtype)
    # Returns of 50 and more (MinAtar's) around quantiles of that size: float32 sums of squares would lose the loss
    target = (th.randn(batch_size, n_target_quantiles, generator=generator) * scale + scale).to(dtype)
    ours, ours_grad = loss_and_gradient(quantile_huber_loss, current, target)
    theirs, theirs_grad = loss_and_gradient(sb3_contrib_loss, current, target)
    tolerance = 1e-5 if dtype == th.float32 else 1e-7  # sb3-contrib's quantile fractions are float32 in any case
    assert ours.dtype == theirs.dtype == dtype
    assert th.allclose(ours, theirs, rtol=tolerance, atol=0)
    assert th.allclose(ours_grad, theirs_grad, rtol=tolerance, atol=tolerance * theirs_grad.abs().max().item())
    assert theirs_grad.abs().sum() > 0  # a gradient to compare


def test_loss_at_the_huber_threshold_and_at_zero() -> None:
    # Integer quantiles: every difference is an integer, so many are exactly 0 and exactly +-1, where the Huber loss
    # switches branch and the asymmetric weight switches side
    current = th.tensor([[0.0, 1.0, 2.0, -1.0], [3.0, 3.0, -2.0, 0.0]], dtype=th.float64)
    target = th.tensor([[0.0, 1.0, 1.0, -1.0, 2.0], [2.0, 4.0, 3.0, -3.0, 0.0]], dtype=th.float64)
    ours, ours_grad = loss_and_gradient(quantile_huber_loss, current, target)
    theirs, theirs_grad = loss_and_gradient(sb3_contrib_loss, current, target)
    assert th.allclose(ours, theirs, rtol=1e-7) and th.allclose(ours_grad, theirs_grad, rtol=1e-7, atol=1e-12)
    # Equal targets (ties in the sort), some of them equal to current quantiles
    repeated = th.tensor([[1.0, 1.0, 1.0, 0.0, 0.0], [-3.0, 3.0, 3.0, 3.0, -3.0]], dtype=th.float64)
    ours, ours_grad = loss_and_gradient(quantile_huber_loss, current, repeated)
    theirs, theirs_grad = loss_and_gradient(sb3_contrib_loss, current, repeated)
    assert th.allclose(ours, theirs, rtol=1e-7) and th.allclose(ours_grad, theirs_grad, rtol=1e-7, atol=1e-12)
    # By hand: one quantile (tau = 1/2) at 0 and one target at 1: delta = 1 >= 0, weight tau, Huber loss 1/2;
    # its gradient is -tau * clip(delta) = -1/2. With the target at -3: weight 1 - tau, Huber 3 - 1/2, gradient 1/2.
    for target_value, loss_value, gradient in [(1.0, 0.25, -0.5), (-3.0, 1.25, 0.5)]:
        one_pair, one_gradient = loss_and_gradient(quantile_huber_loss, current[:1, :1], th.tensor([[target_value]]).double())
        assert one_pair.item() == pytest.approx(loss_value) and one_gradient.item() == pytest.approx(gradient)


@pytest.mark.filterwarnings("error")  # searchsorted warns when it has to copy a strided tensor
def test_strided_quantiles() -> None:
    generator = th.Generator().manual_seed(3)
    current = th.randn(10, 7, generator=generator, dtype=th.float64).t()  # (7, 10), not contiguous
    target = th.randn(12, 7, generator=generator, dtype=th.float64).t()
    assert not current.is_contiguous() and not target.is_contiguous()
    ours, ours_grad = loss_and_gradient(quantile_huber_loss, current, target)
    theirs, theirs_grad = loss_and_gradient(sb3_contrib_loss, current, target)
    assert th.allclose(ours, theirs, rtol=1e-7)
    assert th.allclose(ours_grad, theirs_grad, rtol=1e-7, atol=1e-7 * theirs_grad.abs().max().item())


def test_other_shapes_and_options_are_sb3_contribs() -> None:
    generator = th.Generator().manual_seed(0)
    current, target = th.randn(4, 6, generator=generator), th.randn(4, 6, generator=generator)
    critics, critic_target = th.randn(4, 2, 6, generator=generator), th.randn(4, 1, 9, generator=generator)
    cases = [
        ((critics, critic_target), {}),  # TQC's shapes
        ((current, target), {"sum_over_quantiles": False}),
        ((current, target), {"cum_prob": th.linspace(0.1, 0.9, 6).view(1, -1, 1)}),
    ]
    for (current_quantiles, target_quantiles), kwargs in cases:
        ours = loss_and_gradient(quantile_huber_loss, current_quantiles, target_quantiles, **kwargs)
        theirs = loss_and_gradient(sb3_contrib_loss, current_quantiles, target_quantiles, **kwargs)
        assert all(th.equal(a, b) for a, b in zip(ours, theirs, strict=True)), kwargs
    # A target that needs a gradient gets one, as from sb3-contrib's
    target_with_grad = target.clone().requires_grad_(True)
    quantile_huber_loss(current, target_with_grad).backward()
    reference = target.clone().requires_grad_(True)
    sb3_contrib_loss(current, reference).backward()
    assert target_with_grad.grad is not None and th.allclose(target_with_grad.grad, reference.grad)


SMALL_QRDQN = dict(learning_starts=1_000, batch_size=32, seed=0, policy_kwargs={"net_arch": [32]})


def qrdqn_with_data(algo_class: type[sb3_contrib.QRDQN]) -> sb3_contrib.QRDQN:
    """A QR-DQN that has filled its buffer with 300 steps of CartPole-v1 and not trained yet."""
    model = algo_class("MlpPolicy", "CartPole-v1", **SMALL_QRDQN)
    model.learn(300)
    return model


def test_qrdqn_trains_as_sb3_contribs() -> None:
    reference = qrdqn_with_data(sb3_contrib.QRDQN)
    ours = QRDQN("MlpPolicy", "CartPole-v1", **SMALL_QRDQN)
    ours.set_parameters(reference.get_parameters())  # the policy and the optimizer state
    ours.replay_buffer = copy.deepcopy(reference.replay_buffer)
    ours._logger = reference.logger
    before = copy.deepcopy(ours.policy.state_dict())
    losses_seen = []
    sample = ours.replay_buffer.sample

    def sample_and_look(*args, **kwargs):
        losses_seen.append(sb3_contrib_qrdqn.quantile_huber_loss)  # the loss train() is about to call
        return sample(*args, **kwargs)

    ours.replay_buffer.sample = sample_and_look  # type: ignore[method-assign]
    for model in (reference, ours):
        np.random.seed(1)  # the buffer's sampling
        model.train(gradient_steps=20, batch_size=32)
    assert losses_seen == [quantile_huber_loss] * 20
    assert sb3_contrib_qrdqn.quantile_huber_loss is sb3_contrib_loss  # put back after training
    for (name, ours_param), (_, reference_param) in zip(
        ours.policy.state_dict().items(), reference.policy.state_dict().items(), strict=True
    ):
        assert th.allclose(ours_param, reference_param, rtol=1e-4, atol=1e-6), name
    assert any(not th.equal(before[name], param) for name, param in ours.policy.state_dict().items())  # it trained


def test_the_original_loss_is_back_after_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    model = qrdqn_with_data(QRDQN)
    monkeypatch.setattr(model.replay_buffer, "sample", lambda *args, **kwargs: (_ for _ in ()).throw(RuntimeError("boom")))
    with pytest.raises(RuntimeError, match="boom"):
        model.train(gradient_steps=1, batch_size=32)
    assert sb3_contrib_qrdqn.quantile_huber_loss is sb3_contrib_loss


def test_saved_models_load_with_either_class(tmp_path) -> None:
    ours = qrdqn_with_data(QRDQN)
    ours.save(tmp_path / "ours")
    loaded = sb3_contrib.QRDQN.load(tmp_path / "ours")
    ours_state, loaded_state = ours.policy.state_dict(), loaded.policy.state_dict()
    assert all(th.equal(ours_state[key], loaded_state[key]) for key in ours_state)
    loaded.save(tmp_path / "theirs")
    assert type(QRDQN.load(tmp_path / "theirs")) is QRDQN


def test_the_command_line_trains_this_qrdqn() -> None:
    import rl_zoo3.train

    register()  # what python -m sb3_offon.train does before parsing its arguments
    assert ALGOS["qrdqn"] is QRDQN and rl_zoo3.train.ALGOS["qrdqn"] is QRDQN
