"""
A lambda that chooses itself (``lambda_choice``): at each refresh of the cached lambda-returns, a lambda per transition
chosen from the data, computed from the same pass of the target network as a fixed lambda's returns (no extra pass, no
read-back), for OffOnDQN (``mc_mixing="lambda"``) and OffOnQRDQN alike.

``"median"``, DQN(lambda)'s dynamic return (Daley & Amato 2019; ``DynamicLambdaReplayMemory`` in their code, never
published with figures): per transition, the lambda-returns for lambda = 0, 0.05, ..., 1 (21 of them, with the same
windows, trace cuts and bootstraps as a fixed lambda's), and the one whose value is their median. The target is one of
those returns, so the rule has no bound and no scale: it serves returns of 500 and of 20 alike. The chosen lambda is the
one whose return is the median (where several lambdas give that same return, as where the trace cannot go on, or returns
within float rounding of it, the one of them nearest the middle of the grid). The logged mean and spread count the
transitions where lambda changes the return: those whose trace can go on, with a weight c above 0.

What it does, read from the returns: with Peng's trace (c = 1), G^lam_t - V(s_t) = sum_k (gamma lam)^k delta_{t+k}, the
TD errors delta along the trace, a polynomial in lambda with those coefficients. Where the TD errors along the trace
share a sign (a critic that is off in one direction, as early in training), G^lam is monotone in lambda and its median
over the grid is lambda = 0.5's (the tie rule above absorbs the recurrence's rounding); the rule moves away from 0.5
only where the TD errors disagree in sign, towards the lambda whose return sits between the others. It is robust, not
horizon-seeking: it does not reach for lambda 0.9 where long horizons would pay.

``"autocorrelation"``, one lambda per refresh: the lag-one correlation of the TD errors along the refresh's traces,
clipped to [0, 1] (:func:`td_error_autocorrelation`). A heuristic of this package, not a published rule, and scale-free
(a correlation). The reasoning: an error of the critic that bootstrapping carries from state to state shows as TD
errors that persist along a trajectory, in sign and size (a correlation near 1: early CartPole-v1, whose values are
too low everywhere), and a longer horizon is what corrects it; TD errors that come from noise do not persist (reward or
transition noise: near 0; noise of the critic between neighbouring states: negative), and bootstrapping early, a short
horizon, averages them out. Where a refresh has fewer than two pairs of neighbouring TD errors, or no spread, it keeps
delta1. Both forms of OffOnQRDQN take it, as they take a fixed lambda.

For OffOnQRDQN the rules are applied to the law's mean (the scalar lambda-returns of the mean of the target atoms at the
bootstrap action), and each transition's distributional target is then its chosen lambda's, in the sampled form
(:mod:`sb3_offon.offon_qrdqn.quantile_lambda_returns`).
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sb3_offon.common.lambda_layout import LambdaLayout

LAMBDA_CHOICES = ("fixed", "median", "autocorrelation")
# The rules that choose one lambda for a whole refresh (the others choose one per transition)
PER_REFRESH_CHOICES = ("autocorrelation",)
# The rules that choose one lambda per transition
PER_TRANSITION_CHOICES = tuple(choice for choice in LAMBDA_CHOICES if choice not in ("fixed", *PER_REFRESH_CHOICES))
# The lambdas the median rule chooses among (DQN(lambda)'s grid)
MEDIAN_GRID = np.linspace(0.0, 1.0, 21)
# Returns within this share of their magnitude are tied: a recurrence's rounding, not lambda, tells them apart
TIE_TOLERANCE = 1e-9


@dataclass
class ChosenLambdas:
    """
    The lambdas a rule chose for the transitions of one refresh.

    :param values: one per transition
    :param mean: their mean over the transitions whose trace can go on (where lambda changes the return), or the
        grid's middle if there are none
    :param spread: their standard deviation over the same transitions (0 if none)
    """

    values: np.ndarray
    mean: float
    spread: float


def choose_lambda(
    choice: str, returns_of: Callable[[np.ndarray], np.ndarray], goes_on: np.ndarray
) -> tuple[np.ndarray, ChosenLambdas]:
    """
    The targets and the lambdas that rule ``choice`` picks per transition.

    :param choice: a rule of :data:`LAMBDA_CHOICES` other than ``"fixed"``
    :param returns_of: maps K lambdas, shaped (K, 1, 1), to the scalar lambda-returns of each, shaped (K, transitions)
    :param goes_on: per transition, whether its trace can go on past its first window with a weight above 0 (else
        lambda does not matter, and its lambda is not counted in the mean and spread)
    :return: the chosen returns (transitions,) as float64, and the chosen lambdas
    """
    if choice != "median":
        raise ValueError(f"`lambda_choice` must be one of {LAMBDA_CHOICES}, got {choice!r}")
    grid = MEDIAN_GRID
    returns = returns_of(grid[:, None, None])  # (K, transitions)
    columns = np.arange(returns.shape[1])
    median = returns[np.argsort(returns, axis=0)[len(grid) // 2], columns]
    # Among the lambdas whose return is the median (several where returns tie: lambda does not matter there, or its
    # effect is below the rounding of the recurrence, which can also order tied returns at random by an ulp), the one
    # nearest the middle of the grid
    tied = np.abs(returns - median) <= TIE_TOLERANCE * np.abs(returns).max(axis=0)
    picked = np.argmin(np.where(tied, np.abs(grid - 0.5)[:, None], np.inf), axis=0)
    values = grid[picked]
    counted = values[goes_on]
    mean = float(counted.mean()) if len(counted) else float(grid[len(grid) // 2])
    spread = float(counted.std()) if len(counted) else 0.0
    return median, ChosenLambdas(values=values, mean=mean, spread=spread)


def refresh_lambda(choice: str, layout: LambdaLayout, next_values: np.ndarray, trace: np.ndarray, fallback: float) -> float:
    """
    The lambda that a per-refresh rule (:data:`PER_REFRESH_CHOICES`) chooses for a whole refresh.

    :param choice: the rule
    :param layout: the refresh's transitions (:func:`sb3_offon.common.lambda_layout.lambda_layout`)
    :param next_values: V(s_next) per transition (the atoms' mean for a distributional critic)
    :param trace: (padded) c per transition
    :param fallback: the lambda to keep where the refresh cannot measure its statistic (delta1)
    """
    if choice != "autocorrelation":
        raise ValueError(f"`lambda_choice` {choice!r} does not choose one lambda per refresh")
    correlation = td_error_autocorrelation(layout, next_values, trace)
    return fallback if correlation is None else float(np.clip(correlation, 0.0, 1.0))


def td_error_autocorrelation(layout: LambdaLayout, next_values: np.ndarray, trace: np.ndarray) -> float | None:
    """
    The correlation of neighbouring TD errors along the refresh's traces, pooled over its blocks.

    The TD error of a transition t whose predecessor (the transition ``stride`` steps earlier, in the same block and
    episode) gives V(s_t) is delta_t = R_t + D_t V(s_next) - V(s_t): R_t and D_t the window's discounted reward and
    discount, V(s_next) 0 where no value follows, V(s_t) the predecessor's V(s_next). The pairs (delta_t, delta_{t+stride})
    are taken where the trace of t goes on (in the block, the episode going on, c above 0), as the lambda-return
    weighs them.

    :return: their Pearson correlation, or None with fewer than two pairs or no spread on a side
    """
    stride = layout.stride
    values = layout.padded(next_values.astype(np.float64))
    after, rewards, discounts = layout.padded_value_after(next_values), layout.padded_rewards(), layout.padded_discounts()
    goes_on = layout.goes_on & (trace > 0)
    errors = np.zeros(layout.valid.shape)
    has_error = np.zeros(layout.valid.shape, dtype=bool)
    has_error[:, stride:] = layout.goes_on[:, :-stride]  # the predecessor's episode went on into t
    errors[:, stride:] = rewards[:, stride:] + discounts[:, stride:] * after[:, stride:] - values[:, :-stride]
    paired = has_error[:, :-stride] & goes_on[:, :-stride]
    first, second = errors[:, :-stride][paired], errors[:, stride:][paired]
    if len(first) < 2 or np.ptp(first) == 0.0 or np.ptp(second) == 0.0:
        return None
    return float(np.corrcoef(first, second)[0, 1])
