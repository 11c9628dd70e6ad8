"""
The distributional lambda-returns of OffOnQRDQN: per stored transition, N target atoms for the law of the lambda-return,
computed at a refresh from one batched pass of the target network over the transitions' next states, as DQN(lambda)
computes scalar ones (:mod:`sb3_offon.common.lambda_returns`, whose blocks, windows and trace cuts are reused).

For a transition t, with Z(s) = Z_target(s, a*) the target network's N quantiles at the bootstrap action a* (the argmax
of their mean; of the online network's with ``double_q``), the law of the lambda-return is

- Z^lam_t = r_t (a Dirac) where t terminated its episode;
- Z^lam_t = r_t + gamma Z(s_{t+1}) where t was cut (a time limit, a reset; 0 in place of Z with
  ``mc_truncation="terminal"``) or is the newest transition of a running episode or of its block;
- otherwise Z^lam_t = r_t + gamma [(1 - lam c_{t+1}) Z(s_{t+1}) (+) lam c_{t+1} Z^lam_{t+1}], a mixture of laws
  with those weights, c_{t+1} being 1 after a greedy action and 1 - delta2 after another (as in OffOnDQN).

Unrolled, this is the mixture over horizons k of the k-step laws r_t + ... + gamma^(k-1) r_(t+k-1) + gamma^k Z(s_(t+k)),
with weights (1 - lam c_(t+k)) prod_(i<k) lam c_(t+i) (the last horizon takes what is left: on a terminated episode,
the Dirac at its Monte-Carlo return). With n-step windows (``n_steps`` > 1) each step is a window, as in OffOnDQN.

Two ways to turn that law into N atoms (``lambda_form``):

- ``"sampled"``: per transition and refresh, a horizon is drawn from the weights above (the trace goes on past each
  step with probability lam c, stops otherwise) and the target is that horizon's k-step law, N atoms, with no
  projection. The quantile loss is an expectation over the target's atoms, linear in the target law, so its expected
  value over the draw is the loss against the mixture itself: an unbiased stochastic target. O(n) vectorised work.
  The go-on-or-stop draw is made once per stored step and refresh, and every trace that reaches that step shares it:
  each transition's horizon has the law above, but neighbours' are not independent (where the trace of t - 1 goes on
  past t, its target is r_(t-1) + gamma times the target of t). Minibatches are drawn at random from the whole cache,
  so few of their samples are neighbours.
- ``"projected"``: the backward recursion above, each mixture of 2N weighted atoms projected back onto N atoms, the
  mixture's quantile function at tau_i = (2i - 1) / 2N (the W1 projection, as QR-DQN's own). Deterministic, but each
  step projects a projected law (its error compounds along the trace), and the recursion runs column by column over
  the blocks: a Python loop over a block's length.
"""

from collections.abc import Callable
from typing import Any

import numpy as np

from sb3_offon.common.buffers import OffOnBufferMixin
from sb3_offon.common.lambda_choice import PER_REFRESH_CHOICES, PER_TRANSITION_CHOICES, choose_lambda, refresh_lambda
from sb3_offon.common.lambda_layout import LambdaLayout, lambda_layout
from sb3_offon.common.lambda_returns import LambdaReturnCache, backward_recurrence, scalar_lambda_returns

LAMBDA_FORMS = ("sampled", "projected")

# Maps a batch of next observations (normalised, in the buffer's layout) to (Z_target(s', a*) as (batch, N), a*) as NumPy
TargetQuantilesFn = Callable[[Any], tuple[np.ndarray, np.ndarray]]


def compute_quantile_lambda_returns(
    buffer: OffOnBufferMixin,
    target_quantiles: TargetQuantilesFn,
    n_wanted: int,
    block_size: int,
    gamma: float,
    lam: float,
    qlearning_prob: float,
    cut_is_terminal: bool,
    key: int,
    form: str = "sampled",
    rng: np.random.Generator | None = None,
    env: Any = None,
    choice: str = "fixed",
) -> LambdaReturnCache:
    """
    The N target atoms of the distributional lambda-returns of about ``n_wanted`` stored transitions (see the module's
    docstring), in blocks; the cache's ``returns`` are shaped (transitions, N).

    :param buffer: the Off-On replay buffer
    :param target_quantiles: Z_target(s', a*) and a*, for a batch of next observations
    :param n_wanted: how many transitions to cover (the whole buffer, in one block per env, if it holds no more)
    :param block_size: the length of a block (a trace is cut at a block's end)
    :param gamma: the discount factor
    :param lam: lambda (delta1)
    :param qlearning_prob: delta2: the trace weight after a non-greedy action is 1 - delta2
    :param cut_is_terminal: ``mc_truncation="terminal"``: no value after an episode cut by a time limit or a reset
    :param key: the refresh key to store
    :param form: ``"sampled"`` or ``"projected"``
    :param rng: the generator of the sampled horizons (``"sampled"`` only)
    :param env: the VecNormalize wrapper, if any, to normalise observations and rewards with
    :param choice: ``"fixed"``: ``lam`` for every transition; otherwise a rule of :mod:`sb3_offon.common.lambda_choice`,
        applied to the scalar lambda-returns of the atoms' mean, that chooses a lambda per transition (``lam`` unused;
        the sampled form only) or one per refresh (``lam`` where it cannot choose; both forms)
    """
    if form not in LAMBDA_FORMS:
        raise ValueError(f"`lambda_form` must be one of {LAMBDA_FORMS}, got {form!r}")
    per_transition = choice in PER_TRANSITION_CHOICES
    if per_transition and form != "sampled":
        raise ValueError(f"`lambda_choice` {choice!r} needs the sampled form (`lambda_form='sampled'`), got {form!r}")
    layout = lambda_layout(buffer, n_wanted, block_size, gamma, cut_is_terminal, env)
    next_quantiles, greedy_actions = target_quantiles(layout.inputs["next_observations"])
    trace = layout.trace(greedy_actions, qlearning_prob)
    chosen = None
    if form == "sampled" and rng is None:
        raise ValueError("the sampled form needs a generator (`rng`)")
    next_means = None if choice == "fixed" else next_quantiles.astype(np.float64).mean(axis=1)  # the rules read the mean
    if choice in PER_REFRESH_CHOICES:
        assert next_means is not None
        lam = refresh_lambda(choice, layout, next_means, trace, fallback=lam)
    if per_transition:
        assert rng is not None and next_means is not None

        def returns_of(lambdas: np.ndarray) -> np.ndarray:
            return scalar_lambda_returns(layout, next_means, trace, lambdas)

        _, chosen = choose_lambda(choice, returns_of, (layout.goes_on & (trace > 0))[layout.valid])
        atoms = _sampled_targets_of_own_lambdas(layout, next_quantiles, chosen.values, trace, rng)
    elif form == "sampled":
        assert rng is not None
        atoms = _sampled_targets(layout, next_quantiles, lam * trace, rng)
    else:
        atoms = _projected_targets(layout, next_quantiles, lam * trace)
    return LambdaReturnCache(
        slots=layout.slots,
        envs=layout.envs,
        added_at=layout.added_at,
        returns=atoms.astype(np.float32),
        key=key,
        lam=lam if chosen is None else chosen.mean,
        qlearning_prob=qlearning_prob,
        trace_cut_fraction=layout.trace_cut_fraction(trace),
        whole_buffer=layout.whole_buffer,
        lambda_spread=None if chosen is None else chosen.spread,
    )


def _stop_atoms(layout: LambdaLayout, next_quantiles: np.ndarray) -> np.ndarray:
    """
    (padded, N) What follows a transition's window where its trace stops there: Z(s_next), or 0 where no value follows
    (a termination, or a cut with ``cut_is_terminal``) and the trace could not go on anyway.
    """
    zero = ~layout.goes_on & layout.padded(layout.no_value_after, fill=False).astype(bool)
    padded = layout.padded(next_quantiles.astype(np.float64))
    padded[zero] = 0.0
    return padded


def _sampled_targets(
    layout: LambdaLayout, next_quantiles: np.ndarray, continue_prob: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """
    (transitions, N) One horizon drawn per transition: past each step of its trace, the trace goes on with probability
    ``continue_prob`` (lam c) where it can go on, and stops otherwise; the target is R + D Z at the step it stops at,
    R the discounted rewards up to there and D the discount. R, D and the stopping step are linear recurrences along
    the trace (``backward_recurrence``), so no loop runs over steps.
    """
    stride = layout.stride
    goes_on = layout.goes_on & (rng.random(layout.valid.shape) < continue_prob)
    rewards, discounts = layout.padded_rewards(), layout.padded_discounts()
    coefficients = np.where(goes_on, discounts, 0.0)
    returns = backward_recurrence(rewards, coefficients, stride=stride)  # R_t = r_t + d_t [goes on] R_{t+s}
    # D_t = d_t where the trace stops at t, d_t D_{t+s} where it goes on
    discount_to_stop = backward_recurrence(np.where(goes_on, 0.0, discounts), coefficients, stride=stride)
    # The (padded, flat) index of the step where the trace stops: exact in float64 (sums of integers times 0 or 1)
    cells = np.arange(layout.valid.size, dtype=np.float64).reshape(layout.valid.shape)
    stop = backward_recurrence(np.where(goes_on, 0.0, cells), goes_on.astype(np.float64), stride=stride)
    stop_cells = np.rint(stop[layout.valid]).astype(np.int64)
    stop_atoms = _stop_atoms(layout, next_quantiles).reshape(layout.valid.size, -1)[stop_cells]
    return returns[layout.valid][:, None] + discount_to_stop[layout.valid][:, None] * stop_atoms


def _sampled_targets_of_own_lambdas(
    layout: LambdaLayout, next_quantiles: np.ndarray, lambdas: np.ndarray, trace: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """
    (transitions, N) As :func:`_sampled_targets`, but each transition's trace goes on with its own lambda (``lambdas``,
    one per transition, as ``lambda_choice`` picks them) times c at each step: the trace of t goes on past a step where
    it can with probability lambdas[t] * c there. One uniform per stored step is drawn, as there, and every trace that
    reaches a step compares it with its own lambda; with one lambda for all, the horizons are those of
    :func:`_sampled_targets` on the same draws. A trace's steps are walked one at a time for all transitions at once
    (at most a block's length / ``stride`` rounds), since traces of different lambdas no longer share their ends.
    """
    stride = layout.stride
    uniforms = rng.random(layout.valid.shape)
    rows, columns = np.nonzero(layout.valid)  # the transitions, in the order of padded[valid]
    rewards, discounts = layout.padded_rewards(), layout.padded_discounts()
    n_transitions = len(rows)
    returns, discount_to_stop = np.zeros(n_transitions), np.ones(n_transitions)
    stop_cells = np.zeros(n_transitions, dtype=np.int64)
    walking = np.arange(n_transitions)  # the transitions whose trace has not stopped
    while len(walking):
        row, column = rows[walking], columns[walking]
        returns[walking] += discount_to_stop[walking] * rewards[row, column]
        discount_to_stop[walking] *= discounts[row, column]
        goes_on = layout.goes_on[row, column] & (uniforms[row, column] < lambdas[walking] * trace[row, column])
        stopping = ~goes_on
        stop_cells[walking[stopping]] = row[stopping] * layout.valid.shape[1] + column[stopping]
        walking = walking[goes_on]
        columns[walking] += stride
    stop_atoms = _stop_atoms(layout, next_quantiles).reshape(layout.valid.size, -1)[stop_cells]
    return returns[:, None] + discount_to_stop[:, None] * stop_atoms


def _projected_targets(layout: LambdaLayout, next_quantiles: np.ndarray, continue_weight: np.ndarray) -> np.ndarray:
    """
    (transitions, N) The backward recursion, one block column at a time (the columns ``stride`` apart being the trace's
    steps): where the trace goes on, the mixture (1 - lam c) Z(s_next) (+) lam c Z^lam (next step), projected onto N
    atoms; where it stops, the stop atoms; then r + d times that.
    """
    stride, width = layout.stride, layout.valid.shape[1]
    stop_atoms = _stop_atoms(layout, next_quantiles)
    rewards, discounts = layout.padded_rewards(), layout.padded_discounts()
    targets = np.zeros_like(stop_atoms)
    for column in range(width - 1, -1, -1):
        after = stop_atoms[:, column]
        rows = np.flatnonzero(layout.goes_on[:, column])
        if len(rows):
            after = after.copy()
            weight = continue_weight[rows, column]
            after[rows] = project_mixture(after[rows], 1.0 - weight, targets[rows, column + stride], weight)
        targets[:, column] = rewards[:, column, None] + discounts[:, column, None] * after
    return targets[layout.valid]


def project_mixture(first: np.ndarray, first_weight: np.ndarray, second: np.ndarray, second_weight: np.ndarray) -> np.ndarray:
    """
    The W1 projection onto N atoms of the mixture, row by row, of two laws of N equally weighted atoms each: its
    quantile function F^-1(tau) = min {x : F(x) >= tau} at tau_i = (2i - 1) / 2N, i = 1..N.

    :param first: (rows, N) atoms of the first law
    :param first_weight: (rows,) its weight in the mixture
    :param second: (rows, N) atoms of the second law
    :param second_weight: (rows,) its weight (the two weights sum to 1)
    :return: (rows, N) the projected atoms, sorted
    """
    n_rows, n_atoms = first.shape
    atoms = np.concatenate([first, second], axis=1)
    weights = np.concatenate(
        [
            np.repeat(first_weight[:, None] / n_atoms, n_atoms, axis=1),
            np.repeat(second_weight[:, None] / n_atoms, n_atoms, axis=1),
        ],
        axis=1,
    )
    order = np.argsort(atoms, axis=1, kind="stable")
    atoms = np.take_along_axis(atoms, order, axis=1)
    cumulative = np.cumsum(np.take_along_axis(weights, order, axis=1), axis=1)
    taus = (2.0 * np.arange(n_atoms) + 1.0) / (2.0 * n_atoms)
    # One searchsorted over all rows: row r's cumulative weights (in [0, 1]) are shifted by 2r, and its taus likewise
    shift = 2.0 * np.arange(n_rows)[:, None]
    found = np.searchsorted((cumulative + shift).ravel(), (taus + shift).ravel(), side="left").reshape(n_rows, n_atoms)
    columns = np.minimum(found - 2 * n_atoms * np.arange(n_rows)[:, None], 2 * n_atoms - 1)
    return np.take_along_axis(atoms, columns, axis=1)
