"""
Optuna samplers of the algorithms this package registers into rl-baselines3-zoo (``python -m sb3_offon.train ...
--optimize``): each samples the zoo's DQN or QR-DQN parameters and the target settings of its algorithm, under the
constructor's own argument names.
"""

from typing import Any

import optuna
from rl_zoo3.hyperparams_opt import sample_dqn_params, sample_qrdqn_params

from sb3_offon.common.offon_model import MC_TRUNCATION_OPTIONS
from sb3_offon.offon_dqn.offon_dqn import LOSS_FUNCTIONS, MC_MIXING_OPTIONS, SARSA_TARGET_OPTIONS


def _sample_mc_params(trial: optuna.Trial, lambda_returns: bool = False) -> dict[str, Any]:
    """
    delta1, the probability of the Monte-Carlo target, as a decaying schedule (the paper's shape), and the MC options.
    With ``lambda_returns``, delta1 is lambda and ``mc_mixing`` stays ``"lambda"`` (the YAML's); otherwise it is one of
    the coin-flip modes (the search space of the paper's variants, as it was before the lambda mode existed).
    """
    sampled: dict[str, Any] = {
        "mc_initial_prob": trial.suggest_float("mc_initial_prob", 0.5, 1.0),
        "mc_final_prob": trial.suggest_float("mc_final_prob", 0.0, 0.5),
        "mc_fraction": trial.suggest_float("mc_fraction", 0.1, 1.0),
        "mc_truncation": trial.suggest_categorical("mc_truncation", list(MC_TRUNCATION_OPTIONS)),
    }
    if not lambda_returns:
        coin_flips = [mode for mode in MC_MIXING_OPTIONS if mode != "lambda"]
        sampled["mc_mixing"] = trial.suggest_categorical("mc_mixing", coin_flips)
    return sampled


def _sample_qlearning_params(trial: optuna.Trial, sarsa_target: bool = True) -> dict[str, Any]:
    """
    delta2, the probability of Q-learning given a TD target, as a decaying schedule, and the Sarsa option (not with
    lambda-returns, where delta2 weighs the trace after a non-greedy action and no Sarsa target is made).
    """
    sampled: dict[str, Any] = {
        "qlearning_initial_prob": trial.suggest_float("qlearning_initial_prob", 0.5, 1.0),
        "qlearning_final_prob": trial.suggest_float("qlearning_final_prob", 0.0, 0.5),
        "qlearning_fraction": trial.suggest_float("qlearning_fraction", 0.1, 1.0),
    }
    if sarsa_target:
        sampled["sarsa_target"] = trial.suggest_categorical("sarsa_target", list(SARSA_TARGET_OPTIONS))
    return sampled


def _sample_offon_params(
    trial: optuna.Trial,
    n_actions: int,
    n_envs: int,
    additional_args: dict,
    mc: bool,
    sarsa: bool,
    lambda_returns: bool = False,
) -> dict[str, Any]:
    # DQN's own parameters exactly as the zoo samples them for ``dqn``, so that tuning budgets compare
    hyperparams = sample_dqn_params(trial, n_actions, n_envs, additional_args)
    # Parameters a variant fixes are not sampled: they would only dilute the search
    if mc:
        hyperparams.update(_sample_mc_params(trial, lambda_returns))
    if sarsa:
        hyperparams.update(_sample_qlearning_params(trial, sarsa_target=not lambda_returns))
    hyperparams["loss"] = trial.suggest_categorical("loss", list(LOSS_FUNCTIONS))
    return hyperparams


def sample_offon_paper_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Sampler for the paper's coin-flip targets (``offon_paper``): the zoo's DQN parameters, the delta1 and delta2
    schedules, the string options.

    The schedules are sampled as decaying ones (initial in [0.5, 1], final in [0, 0.5]), the paper's shape.

    :param trial: the Optuna trial
    :param n_actions: number of actions (unused by DQN, part of the zoo's sampler signature)
    :param n_envs: number of training envs
    :param additional_args: the zoo's extra arguments (``using_her_replay_buffer``, ``her_kwargs``)
    :return: the keyword arguments of the algorithm
    """
    return _sample_offon_params(trial, n_actions, n_envs, additional_args, mc=True, sarsa=True)


def sample_dqn_mc_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Sampler for DQNMC hyperparams: as :func:`sample_offon_paper_params`, with delta2 left at 1 (no Sarsa).

    :param trial: the Optuna trial
    :param n_actions: number of actions (unused by DQN, part of the zoo's sampler signature)
    :param n_envs: number of training envs
    :param additional_args: the zoo's extra arguments (``using_her_replay_buffer``, ``her_kwargs``)
    :return: the keyword arguments of the algorithm
    """
    return _sample_offon_params(trial, n_actions, n_envs, additional_args, mc=True, sarsa=False)


def sample_dqn_sarsa_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Sampler for DQNSarsa hyperparams: as :func:`sample_offon_paper_params`, with delta1 left at 0 (no Monte-Carlo).

    :param trial: the Optuna trial
    :param n_actions: number of actions (unused by DQN, part of the zoo's sampler signature)
    :param n_envs: number of training envs
    :param additional_args: the zoo's extra arguments (``using_her_replay_buffer``, ``her_kwargs``)
    :return: the keyword arguments of the algorithm
    """
    return _sample_offon_params(trial, n_actions, n_envs, additional_args, mc=False, sarsa=True)


def sample_offon_lambda_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Sampler for OffOnDQN with ``mc_mixing="lambda"`` (``offon_dqn``, ``offon_watkins``): the zoo's DQN parameters and
    the lambda (delta1) and delta2 schedules, sampled as for :func:`sample_offon_paper_params`; ``mc_mixing`` stays the
    YAML's.

    :param trial: the Optuna trial
    :param n_actions: number of actions (unused by DQN, part of the zoo's sampler signature)
    :param n_envs: number of training envs
    :param additional_args: the zoo's extra arguments (``using_her_replay_buffer``, ``her_kwargs``)
    :return: the keyword arguments of the algorithm
    """
    return _sample_offon_params(trial, n_actions, n_envs, additional_args, mc=True, sarsa=True, lambda_returns=True)


def sample_dqn_nstep_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Sampler for n-step DQN: the zoo's DQN parameters and ``n_steps`` among 3, 5 and 10.

    :param trial: the Optuna trial
    :param n_actions: number of actions (unused by DQN, part of the zoo's sampler signature)
    :param n_envs: number of training envs
    :param additional_args: the zoo's extra arguments (``using_her_replay_buffer``, ``her_kwargs``)
    :return: the keyword arguments of the algorithm
    """
    hyperparams = sample_dqn_params(trial, n_actions, n_envs, additional_args)
    hyperparams["n_steps"] = trial.suggest_categorical("n_steps", [3, 5, 10])
    return hyperparams


def sample_qrdqn_nstep_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Sampler for n-step QR-DQN: the zoo's QR-DQN parameters and ``n_steps`` among 3, 5 and 10.

    :param trial: the Optuna trial
    :param n_actions: number of actions (part of the zoo's sampler signature)
    :param n_envs: number of training envs
    :param additional_args: the zoo's extra arguments (``using_her_replay_buffer``, ``her_kwargs``)
    :return: the keyword arguments of the algorithm
    """
    hyperparams = sample_qrdqn_params(trial, n_actions, n_envs, additional_args)
    hyperparams["n_steps"] = trial.suggest_categorical("n_steps", [3, 5, 10])
    return hyperparams


def sample_offon_qrdqn_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Sampler for OffOnQRDQN: the zoo's QR-DQN parameters (``n_quantiles`` among them) and the lambda (delta1) and delta2
    schedules, sampled as for OffOnDQN's lambda-returns (:func:`sample_offon_lambda_params`).

    :param trial: the Optuna trial
    :param n_actions: number of actions (part of the zoo's sampler signature)
    :param n_envs: number of training envs
    :param additional_args: the zoo's extra arguments (``using_her_replay_buffer``, ``her_kwargs``)
    :return: the keyword arguments of the algorithm
    """
    hyperparams = sample_qrdqn_params(trial, n_actions, n_envs, additional_args)
    hyperparams.update(_sample_mc_params(trial, lambda_returns=True))
    hyperparams.update(_sample_qlearning_params(trial, sarsa_target=False))
    return hyperparams


# By --algo name (zoo.py adds the former names)
SAMPLERS = {
    "dqn_nstep": sample_dqn_nstep_params,
    "offon_paper": sample_offon_paper_params,
    "dqn_mc": sample_dqn_mc_params,
    "dqn_sarsa": sample_dqn_sarsa_params,
    # The search's first choice fixes delta2 at 1 (no Sarsa), as DQNMC does: the same parameters are worth sampling
    "offon_mc_decay": sample_dqn_mc_params,
    "offon_watkins": sample_offon_lambda_params,
    "offon_dqn": sample_offon_lambda_params,
    "qrdqn_nstep": sample_qrdqn_nstep_params,
    "offon_qrdqn": sample_offon_qrdqn_params,
}
