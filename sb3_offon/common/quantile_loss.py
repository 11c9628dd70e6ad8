"""
QR-DQN's quantile Huber loss from sorted targets: the values and gradients of sb3-contrib's ``quantile_huber_loss``
in O(N log N) time and O(N) memory per sample instead of O(N^2).

sb3-contrib builds the loss from all pairwise differences with autograd: about ten tensors of batch x quantiles x
quantiles (32 x 200 x 200 with QR-DQN's defaults) forward and as many backward, 25 ms per gradient step on one thread of
a 2-core VM, where DQN's whole gradient step on the MinAtar network takes 2.5 ms. But each current quantile's loss is
a piecewise polynomial of degree two in the targets: linear in the targets more than 1 away, quadratic within 1, with
one weight below and another above. With the targets sorted and their prefix sums (of the targets and of their
squares), three binary searches per current quantile give the count and sums of each piece, hence the loss and its
closed-form gradient: 1.5 ms on the same thread. The sums are taken in float64, so that the quadratic pieces do not
cancel away float32's digits when returns are large. Values and gradients agree with sb3-contrib's to float rounding
(tests/test_quantile_loss.py: random quantiles at several scales, equal targets, differences of exactly 0 and 1).
"""

from typing import Any

import torch as th


class QuantileHuberLoss(th.autograd.Function):
    """
    The quantile Huber loss (kappa = 1) of QR-DQN, summed over the current quantiles and averaged over the batch and the
    target quantiles, with its gradient with respect to the current quantiles only (the targets are constants).

    For one sample, current quantile theta with fraction tau = (i + 0.5) / N, and the differences d = T - theta to its
    targets T: each pair costs (1 - tau) h(d) where d < 0 and tau h(d) where d >= 0, with h(d) = d^2 / 2 where abs(d) <= 1
    and abs(d) - 1/2 beyond. The targets fall in four pieces: A, T < theta - 1 (cost (1 - tau)(theta - T - 1/2)); B,
    theta - 1 <= T < theta ((1 - tau)(T - theta)^2 / 2); C, theta <= T <= theta + 1 (tau (T - theta)^2 / 2); D,
    T > theta + 1 (tau (T - theta - 1/2)). Each piece's sum needs only its count n and its sums S1 of T and S2 of T^2,
    read off the prefix sums of the sorted targets; the derivative with respect to theta is (1 - tau) n_A -
    (1 - tau)(S1_B - n_B theta) - tau (S1_C - n_C theta) - tau n_D. (At the joins the cost and its derivative are
    continuous, so which piece a tie falls in does not matter.)
    """

    @staticmethod
    def forward(ctx: Any, current_quantiles: th.Tensor, target_quantiles: th.Tensor) -> th.Tensor:
        batch_size, _ = current_quantiles.shape
        n_targets = target_quantiles.shape[-1]
        costs, slopes = _quantile_costs_and_slopes(current_quantiles, target_quantiles)
        scale = batch_size * n_targets
        loss = costs.sum() / scale
        gradient = slopes / scale
        ctx.save_for_backward(gradient.to(current_quantiles.dtype))
        return loss.to(current_quantiles.dtype)

    @staticmethod
    def backward(ctx: Any, grad_output: th.Tensor) -> tuple[th.Tensor, None]:
        (gradient,) = ctx.saved_tensors
        return grad_output * gradient, None


def _quantile_costs_and_slopes(current_quantiles: th.Tensor, target_quantiles: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """
    Per sample and current quantile (batch_size, n_quantiles), in float64: the quantile Huber cost summed over the
    targets, and its derivative with respect to the current quantile (see :class:`QuantileHuberLoss`).
    """
    batch_size, n_quantiles = current_quantiles.shape
    n_targets = target_quantiles.shape[-1]
    theta = current_quantiles.detach().double().contiguous()  # searchsorted copies (and warns) otherwise
    targets = target_quantiles.detach().double().sort(dim=-1).values.contiguous()
    zeros = targets.new_zeros(batch_size, 1)
    sums = th.cat([zeros, targets.cumsum(dim=-1)], dim=-1)  # sums[:, k]: the k smallest targets' sum
    squares = th.cat([zeros, targets.square().cumsum(dim=-1)], dim=-1)
    fractions = (th.arange(n_quantiles, device=theta.device, dtype=th.float64) + 0.5) / n_quantiles

    # How many targets lie below theta - 1, below theta, and at or below theta + 1
    k_a = th.searchsorted(targets, theta - 1.0, side="left")
    k_b = th.searchsorted(targets, theta, side="left")
    k_c = th.searchsorted(targets, theta + 1.0, side="right")
    sum_a, sum_b, sum_c = sums.gather(-1, k_a), sums.gather(-1, k_b), sums.gather(-1, k_c)
    square_a, square_b, square_c = squares.gather(-1, k_a), squares.gather(-1, k_b), squares.gather(-1, k_c)
    n_a, n_b, n_c, n_d = k_a.double(), (k_b - k_a).double(), (k_c - k_b).double(), (n_targets - k_c).double()
    s1_b, s1_c, s1_d = sum_b - sum_a, sum_c - sum_b, sums[:, -1:] - sum_c
    s2_b, s2_c = square_b - square_a, square_c - square_b

    below = n_a * (theta - 0.5) - sum_a + 0.5 * (s2_b - 2.0 * theta * s1_b + n_b * theta.square())
    above = 0.5 * (s2_c - 2.0 * theta * s1_c + n_c * theta.square()) + s1_d - n_d * (theta + 0.5)
    costs = (1.0 - fractions) * below + fractions * above
    slopes = (1.0 - fractions) * (n_a - s1_b + n_b * theta) - fractions * (s1_c - n_c * theta + n_d)
    return costs, slopes


class WeightedQuantileHuberLoss(th.autograd.Function):
    """
    QR-DQN's quantile Huber loss with a weight per sample (prioritised replay's importance weights): the mean over the
    batch of weight x (the sample's cost summed over the current quantiles, averaged over the targets). With unit
    weights, the value and gradient of :class:`QuantileHuberLoss`. Its second output is each sample's unweighted loss
    (what prioritised replay takes as the sample's error, as :func:`per_sample_quantile_huber_loss` computes it), from
    the same pass, without a gradient.
    """

    @staticmethod
    def forward(
        ctx: Any, current_quantiles: th.Tensor, target_quantiles: th.Tensor, weights: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor]:
        batch_size, _ = current_quantiles.shape
        n_targets = target_quantiles.shape[-1]
        costs, slopes = _quantile_costs_and_slopes(current_quantiles, target_quantiles)
        weights = weights.detach().double().reshape(-1, 1)
        scale = batch_size * n_targets
        ctx.save_for_backward((weights * slopes / scale).to(current_quantiles.dtype))
        per_sample = (costs.sum(dim=1) / n_targets).to(current_quantiles.dtype)
        ctx.mark_non_differentiable(per_sample)
        return ((weights * costs).sum() / scale).to(current_quantiles.dtype), per_sample

    @staticmethod
    def backward(ctx: Any, grad_output: th.Tensor, _grad_per_sample: th.Tensor) -> tuple[th.Tensor, None, None]:
        (gradient,) = ctx.saved_tensors
        return grad_output * gradient, None, None


def per_sample_quantile_huber_loss(current_quantiles: th.Tensor, target_quantiles: th.Tensor) -> th.Tensor:
    """Each sample's quantile Huber loss (summed over the current quantiles, averaged over the targets), no gradient."""
    with th.no_grad():
        costs, _ = _quantile_costs_and_slopes(current_quantiles, target_quantiles)
        return (costs.sum(dim=1) / target_quantiles.shape[-1]).to(current_quantiles.dtype)


def quantile_huber_loss(
    current_quantiles: th.Tensor,
    target_quantiles: th.Tensor,
    cum_prob: th.Tensor | None = None,
    sum_over_quantiles: bool = True,
) -> th.Tensor:
    """
    sb3-contrib's ``quantile_huber_loss`` (same arguments, same result), through :class:`QuantileHuberLoss` in QR-DQN's
    case: current quantiles of shape (batch_size, n_quantiles), targets (batch_size, n_target_quantiles) that need no
    gradient, the midpoints as quantile fractions, summed over the quantiles. Any other case (TQC's critics, given
    fractions, a target with a gradient) is sb3-contrib's function.

    :param current_quantiles: current estimate of quantiles, (batch_size, n_quantiles) for the sorted-target pass
    :param target_quantiles: target quantiles, (batch_size, n_target_quantiles) for the sorted-target pass
    :param cum_prob: quantile fractions (None: the midpoints (i + 0.5) / n_quantiles)
    :param sum_over_quantiles: sum over the current quantiles (True, QR-DQN's) or average
    :return: the loss
    """
    sorted_targets = (
        cum_prob is None
        and sum_over_quantiles
        and current_quantiles.ndim == 2
        and target_quantiles.ndim == 2
        and current_quantiles.shape[0] == target_quantiles.shape[0]
        and not target_quantiles.requires_grad
    )
    if sorted_targets:
        return QuantileHuberLoss.apply(current_quantiles, target_quantiles)
    from sb3_contrib.common.utils import quantile_huber_loss as sb3_contrib_quantile_huber_loss

    return sb3_contrib_quantile_huber_loss(current_quantiles, target_quantiles, cum_prob, sum_over_quantiles)
