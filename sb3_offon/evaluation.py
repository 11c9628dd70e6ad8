"""
Evaluation with a small exploration rate, as the Atari protocols evaluate: the greedy action, and with probability
``exploration_rate`` a uniformly random one (Dopamine's ``epsilon_eval`` 0.001).

A greedy policy can wait forever in a game that needs an action to go on (Breakout's serve), and SB3's stochastic
prediction for DQN uses the training schedule's current rate (0.01 at the end of it), not the protocol's; so the zoo's
Atari evaluation (``deterministic=False``) is not the protocol's. :class:`EpsilonGreedyPredictor` wraps any model with
``predict`` (DQN, QR-DQN, OffOnDQN, ...), :class:`EpsilonGreedyEvalCallback` is SB3's ``EvalCallback`` evaluating it,
and :func:`final_evaluation` the protocol's score after training (100 games), written to ``final_evaluation.npz``.
"""

import time
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv

FINAL_EVALUATION_FILE = "final_evaluation.npz"


class EpsilonGreedyPredictor:
    """
    A model's greedy (deterministic) actions, each replaced with probability ``exploration_rate`` by a uniformly random
    one; everything else (``save``, ``num_timesteps``, ...) is the model's.

    :param model: an algorithm with a discrete action space
    :param exploration_rate: the probability of a random action
    :param seed: the seed of the generator that draws them (a list of ints: NumPy's ``SeedSequence`` entropy)
    """

    def __init__(self, model: BaseAlgorithm, exploration_rate: float, seed: int | list[int] | None = None) -> None:
        if not 0.0 <= exploration_rate <= 1.0:
            raise ValueError(f"`exploration_rate` must be in [0, 1], got {exploration_rate}")
        if not isinstance(model.action_space, spaces.Discrete):
            raise ValueError(f"`model` must have a Discrete action space for epsilon-greedy actions, got {model.action_space}")
        self.model = model
        self.exploration_rate = exploration_rate
        self.rng = np.random.default_rng(seed)

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """The greedy actions, a random one in each env with probability ``exploration_rate`` (``deterministic`` ignored)."""
        actions, state = self.model.predict(observation, state, episode_start, deterministic=True)
        actions = np.array(actions)
        explore = self.rng.random(actions.shape) < self.exploration_rate
        if explore.any():
            n_actions = int(self.model.action_space.n)  # type: ignore[attr-defined]
            actions[explore] = self.rng.integers(n_actions, size=int(explore.sum()))
        return actions, state

    def __getattr__(self, name: str) -> Any:
        return getattr(self.model, name)


class EpsilonGreedyEvalCallback(EvalCallback):
    """
    SB3's ``EvalCallback`` evaluating the epsilon-greedy policy of :class:`EpsilonGreedyPredictor` (the evaluations,
    best model and logs as ``EvalCallback`` writes them).

    :param eval_env: the evaluation env
    :param exploration_rate: the probability of a random action at each evaluation step
    :param seed: the seed of the random actions' generator
    :param kwargs: the other arguments of ``EvalCallback`` (``deterministic`` is not one: the policy is the above)
    """

    def __init__(self, eval_env: Any, exploration_rate: float = 0.001, seed: int | None = None, **kwargs: Any) -> None:
        kwargs.pop("deterministic", None)
        super().__init__(eval_env, deterministic=True, **kwargs)
        self.exploration_rate = exploration_rate
        self.seed = seed

    def _on_step(self) -> bool:
        if not (self.eval_freq > 0 and self.n_calls % self.eval_freq == 0):
            return super()._on_step()
        model = self.model
        # A generator seeded by the seed and the step: the same evaluation whether the run was resumed or not
        seed = None if self.seed is None else [self.seed, int(self.num_timesteps)]
        self.model = EpsilonGreedyPredictor(model, self.exploration_rate, seed=seed)  # type: ignore[assignment]
        try:
            return super()._on_step()
        finally:
            self.model = model


def final_evaluation(
    model: BaseAlgorithm, env: VecEnv, n_episodes: int, exploration_rate: float, folder: str | Path, seed: int | None = None
) -> dict[str, Any]:
    """
    The score after training: ``n_episodes`` episodes of the epsilon-greedy policy (whole episodes as the ``Monitor``
    beneath ``env`` counts them), written to ``folder/final_evaluation.npz`` (``results``, ``ep_lengths``, ``timesteps``:
    the model's step count, ``exploration_rate``, ``wall_time_s``).

    :param model: the trained model
    :param env: the evaluation env (one env: the episodes are then the first ``n_episodes`` ones, not a sample biased
        towards short episodes as with several)
    :param n_episodes: how many episodes
    :param exploration_rate: the probability of a random action
    :param folder: where the file goes
    :param seed: the seed of the random actions' generator
    :return: what the file holds
    """
    start = time.perf_counter()
    predictor = EpsilonGreedyPredictor(model, exploration_rate, seed=seed)
    returns, lengths = evaluate_policy(
        predictor,  # type: ignore[arg-type]
        env,
        n_eval_episodes=n_episodes,
        deterministic=True,
        return_episode_rewards=True,
        warn=False,
    )
    record = {
        "results": np.asarray(returns, dtype=np.float64),
        "ep_lengths": np.asarray(lengths, dtype=np.int64),
        "timesteps": np.int64(model.num_timesteps),
        "exploration_rate": np.float64(exploration_rate),
        "wall_time_s": np.float64(time.perf_counter() - start),
    }
    np.savez(Path(folder) / FINAL_EVALUATION_FILE, **record)
    return record
