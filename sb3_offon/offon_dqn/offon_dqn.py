import warnings
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import obs_as_tensor
from stable_baselines3.dqn import DQN
from stable_baselines3.dqn.policies import DQNPolicy
from torch.nn import functional as F

from sb3_offon.common.buffers import (
    OffOnBufferMixin,
    reward_scale,
)
from sb3_offon.common.chunks import ChunkedMinibatchesMixin
from sb3_offon.common.non_finite import NonFiniteChecksMixin
from sb3_offon.common.offon_arguments import OFFON_PARAMETERS as OFFON_PARAMETERS
from sb3_offon.common.offon_arguments import OffOnArgumentsMixin, constructor_arguments
from sb3_offon.common.offon_model import check_option, check_positive_integer
from sb3_offon.offon_dqn.coin_flip_targets import CoinFlipTargetsMixin
from sb3_offon.offon_dqn.lambda_training import LambdaTrainingMixin
from sb3_offon.offon_dqn.policies import CnnPolicy, MlpPolicy, MultiInputPolicy, OffOnDQNPolicy

SelfOffOnDQN = TypeVar("SelfOffOnDQN", bound="OffOnDQN")

MC_MIXING_OPTIONS = ("sample", "convex", "max", "lambda")
SARSA_TARGET_OPTIONS = ("sampled", "expected")
LOSS_FUNCTIONS = {"huber": F.smooth_l1_loss, "mse": F.mse_loss}


class OffOnDQN(
    NonFiniteChecksMixin, CoinFlipTargetsMixin, LambdaTrainingMixin, ChunkedMinibatchesMixin, OffOnArgumentsMixin, DQN
):
    """
    Offline-Online DQN: a DQN whose regression target is drawn, per sample, among the offline Monte-Carlo return
    of the finished episode, the Q-learning target and the Sarsa target.

    Paper: Kim, "Deep Reinforcement Learning by Balancing Offline Monte Carlo and Online Temporal Difference Use
    Based on Environment Experiences", Symmetry 12(10):1685, 2020. https://doi.org/10.3390/sym12101685

    Defaults: the lambda-return mode below (``mc_mixing="lambda"``) with lambda = 0.9 throughout training and Peng's
    Q(lambda) (delta2 = 0, no trace cuts): the configuration that a search on tuning seeds chose and that a
    head-to-head on fresh seeds 20-29 found not below DQN's final return on any of four tasks and with a normalised
    area under the learning curve above n-step DQN's across them (``results/headtohead2/README.md``). The paper's
    configuration, described first below, is one argument set away:
    ``OffOnDQN(policy, env, **sb3_offon.PAPER_TARGETS)`` (``--algo offon_paper`` on the command line).

    With probability delta1 (``mc_*``), and when the return G_t of the transition's episode is known, the target is
    G_t. Otherwise it is a TD target: Q-learning, y = r + gamma * (1 - d) * max_a Q_target(s', a), with probability
    delta2 (``qlearning_*``), else Sarsa. Both probabilities decay linearly like the exploration rate.

    Where the paper is loose, this implementation reads it as follows (and keeps the paper's choice as an option):

    - The paper's pseudo-code swaps "online" and "offline" and decays delta1 per episode; here both schedules move
      with training progress (env steps), as SB3's exploration rate does.
    - The Monte-Carlo return is the discounted return G_t = r_t + gamma * G_{t+1}, computed once when the episode
      ends and stored next to the transitions in the replay buffer (the paper's episode buffer Omega).
    - An episode cut by a time limit is not terminal: by default its return is bootstrapped from the target network
      at the final observation (``mc_truncation="bootstrap"``); ``"terminal"`` is what the paper's code base did;
      ``"drop"`` leaves its returns unknown (its samples take TD targets), which keeps ``mc_mixing="max"`` a true
      lower bound in a deterministic environment whatever the sign of the rewards.
    - Sarsa bootstraps from the action actually taken at s' (recorded in the buffer; ``sarsa_target="sampled"``), or
      from the expectation under the current epsilon-greedy policy (``"expected"``).
    - The paper uses a squared error; SB3's DQN uses the Huber loss, which is the default here (``loss="mse"`` for
      the paper's).
    - With VecNormalize's reward normalisation, the buffer keeps raw rewards (as SB3 does) and raw returns; sampled
      returns are divided by the same factor as the rewards (without the per-reward clip), and a truncation's
      bootstrap, in the normalised units the network learnt, is converted to raw units when the episode ends.

    ``mc_mixing="lambda"`` reads delta1 and delta2 as weights instead of coin flips. The target of a transition t is
    its lambda-return G_t: r_t where t terminated its episode; r_t + gamma * V(s_{t+1}) where t was cut (by a time
    limit or a reset) or is the newest transition of an episode still running; otherwise
    G_t = r_t + gamma * [(1 - lam * c_{t+1}) * V(s_{t+1}) + lam * c_{t+1} * G_{t+1}], with V(s) = max_a Q_target(s, a),
    c_{t+1} = 1 where the recorded a_{t+1} is the target network's greedy action at s_{t+1} and 1 - delta2 elsewhere.

    - lambda = delta1, the current value of the ``mc_*`` schedule: how far the target looks ahead, from the one-step
      Q-learning target (lambda = 0) to the Monte-Carlo return (lambda = 1 with no cuts).
    - delta2, the current value of the ``qlearning_*`` schedule: how strictly the target follows the greedy policy.
      delta2 = 1 cuts the trace at every non-greedy action: Watkins's Q(lambda) (Watkins 1989), whose fixed point is Q*
      on stochastic tasks too; delta2 = 0 never cuts: Peng's Q(lambda) (Peng & Williams 1996; Kozuno et al., "Revisiting
      Peng's Q(lambda) for Modern Reinforcement Learning", ICML 2021), faster but biased toward the behaviour policy.
    - The returns are computed as in DQN(lambda) (Daley & Amato, "Reconciling lambda-Returns with Experience Replay",
      NeurIPS 2019): at the first training call after each target network update (or every
      ``lambda_refresh_interval`` env steps), blocks of ``lambda_block_size`` consecutive stored transitions are picked
      at random until they hold as many transitions as will be trained on before the next refresh (each once, in
      random order, then again if more are needed); one batched pass of the target network gives V and the greedy
      actions of their next states, and the recursion runs backwards over all blocks at once. Minibatches are drawn
      from these cached returns. The network behind a cached value is the current target network with the default
      refresh (it does not change between two of its updates), and at most ``lambda_refresh_interval`` env steps
      old otherwise; lambda and delta2 are the schedules' values at the refresh. Transitions added since the last
      refresh wait for the next one, and cached ones overwritten since are skipped. One exception keeps a young
      buffer from starving: a cache that holds the whole buffer is computed afresh (same target network) once the
      buffer holds twice as many transitions, so at least half of what is stored is trained on, and the recomputations
      while it grows cost at most twice its final size. Without it, with SB3's default ``target_update_interval`` of
      10,000 and ``learning_starts`` of 100, a run's first 10,000 steps would train on its first 100 transitions only.
    - Cost: one target network pass per computed return, which replaces the pass per sampled transition of the
      other modes, plus O(n log n) NumPy work for n returns; independent of ``buffer_size`` except for picking the
      blocks (O(buffer_size / lambda_block_size)). When the buffer holds no more than a refresh needs, each env's
      whole history is one block, and no trace is cut at a block's end; otherwise the last transition of a block
      bootstraps as the newest of a running episode does (a truncated lambda-return, as in DQN(lambda)).
    - ``mc_truncation``: ``"bootstrap"`` and ``"drop"`` end a cut episode's trace with gamma * V(s_T) from the target
      network of the refresh (the lambda-return there is the one-step TD target, so no return is left unknown);
      ``"terminal"`` ends it with 0, as after a termination. ``sarsa_target`` plays no part.
    - ``n_steps`` > 1: the steps of the recursion are n-step windows, as in n-step DQN: r_t becomes the discounted sum
      of the rewards of t's window (up to n steps, fewer where the episode did not go on), gamma becomes gamma^k for a
      window of k steps, s_{t+1} becomes s_{t+k}, and the trace goes on to G_{t+n} with c_{t+n}. This is the
      lambda-return over the n-, 2n-, 3n-step returns; lambda = 0 gives n-step DQN's target. As in n-step DQN, the
      actions inside a window are not checked against the greedy policy.
    - Logged: ``train/lambda`` and ``train/trace_cut_fraction``, the share of the continuations whose trace weight
      c_{t+1} was below 1 (non-greedy next actions with delta2 > 0), both of the refresh in use.

    ``double_q=True`` is double Q-learning (van Hasselt, Guez & Silver, "Deep Reinforcement Learning with Double
    Q-learning", AAAI 2016) in every target that bootstraps: V(s) = Q_target(s, argmax_a Q(s, a)), the action picked by
    the online network and valued by the target network, replaces max_a Q_target(s, a) in the Q-learning target of the
    coin-flip modes (and in Sarsa's where the next action is unknown), in the bootstrap of a truncated episode's return,
    and in the lambda-returns, where the trace-cut test also compares the recorded next action with that online argmax
    (the greedy policy being learnt). With ``n_steps`` > 1 it applies at the n-th next state. Expected Sarsa is
    unchanged (it does not maximise). Cost: one forward pass of the online network beside each pass of the target
    network, on the same batch. The online network behind an argmax is the one of the moment the target is computed:

    - coin-flip modes: at the start of each chunk of gradient steps (one chunk holds all of a training call's steps
      unless their observations pass 64 MiB, see :mod:`sb3_offon.common.chunks`), so at most ``gradient_steps``
      - 1 steps older than the step that trains on it, as the target network's values are (SB3's own double-DQN-less
      loop would take it at each step);
    - a truncated episode's bootstrap: when the episode ends, never refreshed (as with ``double_q=False``);
    - ``mc_mixing="lambda"``: at the refresh, so as old as the cached return, at most ``target_update_interval`` env
      steps (or ``lambda_refresh_interval``), while the target network's values there are current.

    Where the target network is updated at least as often as training calls run (the zoo's CartPole-v1 settings:
    every 10 env steps, training every 256), the two networks are equal whenever a target is computed, and
    ``double_q`` changes nothing.

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, ...)
    :param env: The environment to learn from (if registered in Gym, can be str)
    :param learning_rate: The learning rate, it can be a function of the current progress remaining (from 1 to 0)
    :param buffer_size: size of the replay buffer
    :param learning_starts: how many steps of the model to collect transitions for before learning starts
    :param batch_size: Minibatch size for each gradient update
    :param tau: the soft update coefficient ("Polyak update", between 0 and 1) default 1 for hard update
    :param gamma: the discount factor (also of the Monte-Carlo returns)
    :param train_freq: Update the model every ``train_freq`` steps. Alternatively pass a tuple of frequency and unit
        like ``(5, "step")`` or ``(2, "episode")``.
    :param gradient_steps: How many gradient steps to do after each rollout (see ``train_freq``).
        Set to ``-1`` means to do as many gradient steps as steps done in the environment during the rollout.
    :param replay_buffer_class: Replay buffer class to use. If ``None``, an Off-On buffer matching the observation
        space and ``n_steps`` is selected. A buffer that is not an ``OffOnBufferMixin`` (``HerReplayBuffer``, say)
        records no returns nor next actions: training then uses Q-learning targets only (with a warning).
    :param replay_buffer_kwargs: Keyword arguments to pass to the replay buffer on creation. An Off-On buffer always
        gets the model's ``gamma`` (and, for ``OffOnNStepReplayBuffer``, ``n_steps`` where the model's is above 1), so
        that returns and TD targets share one discount; a different value given here is a ``ValueError``.
    :param optimize_memory_usage: Enable a memory efficient variant of the replay buffer at a cost of more complexity.
        SB3 allows it only without ``handle_timeout_termination``, so the one-step, n-step and λ targets take a
        time-limit truncation for a termination (as SB3's DQN does with it); the Monte-Carlo returns still bootstrap
        it per ``mc_truncation``. An episode cut by an env reset (a new ``learn()``) bootstraps from the next
        episode's first observation, whose slot holds its next observation (as SB3's DQN's target does).
    :param n_steps: When n_step > 1, uses n-step returns for the TD targets; Sarsa then uses the action taken at the
        n-th next state. Monte-Carlo returns are unaffected. With ``mc_mixing="lambda"``, the lambda-return is taken
        over n-step returns (see above).
    :param target_update_interval: update the target network every ``target_update_interval`` environment steps.
    :param exploration_fraction: fraction of entire training period over which the exploration rate is reduced
    :param exploration_initial_eps: initial value of random action probability
    :param exploration_final_eps: final value of random action probability
    :param max_grad_norm: The maximum value for the gradient clipping
    :param mc_initial_prob: initial delta1, the probability of the Monte-Carlo target (where the return is known);
        lambda with ``mc_mixing="lambda"``. Default 0.9 (the paper: 0.99)
    :param mc_final_prob: final delta1. Default 0.9 (the paper: 0.01)
    :param mc_fraction: fraction of the training period over which delta1 goes from initial to final
    :param qlearning_initial_prob: initial delta2, the probability of the Q-learning target given a TD target
        (Sarsa otherwise); with ``mc_mixing="lambda"``, how strictly the trace is cut after non-greedy actions.
        Default 0.0, Peng's Q(lambda) (the paper: 0.99)
    :param qlearning_final_prob: final delta2. Default 0.0 (the paper: 0.01)
    :param qlearning_fraction: fraction of the training period over which delta2 goes from initial to final
    :param mc_mixing: ``"sample"`` draws the Monte-Carlo target with probability delta1 (the paper);
        ``"convex"`` uses y = delta1 * G + (1 - delta1) * y_TD where G is known (mixed Monte-Carlo,
        Ostrovski et al. 2017; Hausknecht & Stone 2016); ``"max"`` uses the return as a lower bound,
        y = max(G, y_TD), where the delta1 draw picks it and G is known (MCAC, Wilcox et al. 2022; Optimality
        Tightening, He et al. 2017; Self-Imitation Learning, Oh et al. 2018). In a deterministic environment any
        observed return after (s, a) is achievable, so it bounds Q* from below however old the policy that earned it;
        in a stochastic one it is optimistic. ``"lambda"``: every target is the lambda-return described above
        (lambda = delta1, trace cuts weighted by delta2; Watkins's and Peng's Q(lambda), DQN(lambda)); the default.
    :param sarsa_target: ``"sampled"`` bootstraps from the recorded next action (Q-learning where it is unknown);
        ``"expected"`` from the expectation under the current epsilon-greedy policy (Expected Sarsa)
    :param mc_truncation: return after a time-limit truncation: ``"bootstrap"``, gamma * max_a Q_target(s_T, a)
        computed with the target network when the episode ends; ``"terminal"``, 0; ``"drop"``, none: the episode's
        returns stay unknown and its samples take TD targets. A bootstrapped return contains a network estimate and a
        "terminal" one leaves out the rewards after the cut (optimistic where they are negative), so with
        ``mc_mixing="max"`` only ``"drop"`` bounds Q* from below with observed returns alone. A bootstrap is
        computed once, when the episode ends, and not refreshed: episodes cut before ``learning_starts`` keep the
        untrained target network's estimate (``"drop"`` avoids it)
    :param loss: ``"huber"`` (SB3's DQN) or ``"mse"`` (the paper)
    :param lambda_block_size: ``mc_mixing="lambda"``: the number of consecutive stored transitions whose lambda-returns
        are computed together (a trace is cut at a block's end unless the episode ended there first)
    :param lambda_refresh_interval: ``mc_mixing="lambda"``: recompute the cached lambda-returns every this many env
        steps; None (default): whenever the target network is updated (every ``target_update_interval`` steps). Set it
        with soft target updates every step (``tau`` < 1), where refreshing at each update would cost most
    :param lambda_choice: ``mc_mixing="lambda"``: ``"fixed"`` (default), lambda is delta1 for every transition;
        ``"median"``, a lambda per transition chosen at each refresh from the data (DQN(lambda)'s dynamic return: the
        median of the lambda-returns for lambda = 0, 0.05, ..., 1; :mod:`sb3_offon.common.lambda_choice`), delta1 then
        unused; ``"autocorrelation"``, one lambda per refresh, the lag-one correlation of the TD errors along the
        traces, clipped to [0, 1] (delta1 where it cannot be measured). The chosen lambdas' mean (``train/lambda``) and,
        per transition, their standard deviation (``train/lambda_std``) are logged
    :param lambda_horizon: ``mc_mixing="lambda"``: lambda stated as a horizon in env steps: None (default), lambda is
        delta1's schedule; h, lambda for the whole run is the one whose lambda-return contracts like an h-step return
        with the model's ``gamma``, lambda_h = (1 - gamma^(h-1)) / (1 - gamma^h) (:func:`sb3_offon.lambda_for_horizon`;
        3: 0.670 and 5: 0.804 at gamma 0.99), over n-step windows that of h / n windows with discount gamma^n (h =
        ``n_steps``: lambda 0). It takes the place of ``mc_initial_prob`` and ``mc_final_prob``, which stay at their
        defaults
    :param double_q: double Q-learning in every bootstrap (see above): the online network picks the action, the target
        network values it. Default False (DQN's max over the target network)
    :param non_finite: what a non-finite reward does: ``"raise"`` (default) a ``NonFiniteError`` naming the env and step,
        nothing of that step stored; ``"skip"`` a warning, the step's transitions not stored and the running episodes
        cut there as truncations. A non-finite loss always raises (:mod:`sb3_offon.common.non_finite`)
    :param stats_window_size: Window size for the rollout logging, specifying the number of episodes to average
        the reported success rate, mean episode length, and mean reward over
    :param tensorboard_log: the log location for tensorboard (if None, no logging)
    :param policy_kwargs: additional arguments to be passed to the policy on creation
    :param verbose: Verbosity level: 0 for no output, 1 for info messages (such as device or wrappers used), 2 for
        debug messages
    :param seed: Seed for the pseudo random generators, including the generator of the target draws
    :param device: Device (cpu, cuda, ...) on which the code should be run.
        Setting it to auto, the code will be run on the GPU if possible.
    :param _init_setup_model: Whether or not to build the network at the creation of the instance
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": MlpPolicy,
        "CnnPolicy": CnnPolicy,
        "MultiInputPolicy": MultiInputPolicy,
    }

    def __init__(
        self,
        policy: str | type[DQNPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 100,
        batch_size: int = 32,
        tau: float = 1.0,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 4,
        gradient_steps: int = 1,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        n_steps: int = 1,
        target_update_interval: int = 10000,
        exploration_fraction: float = 0.1,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.05,
        max_grad_norm: float = 10,
        mc_initial_prob: float = 0.9,
        mc_final_prob: float = 0.9,
        mc_fraction: float = 1.0,
        qlearning_initial_prob: float = 0.0,
        qlearning_final_prob: float = 0.0,
        qlearning_fraction: float = 1.0,
        mc_mixing: str = "lambda",
        sarsa_target: str = "sampled",
        mc_truncation: str = "bootstrap",
        loss: str = "huber",
        lambda_block_size: int = 100,
        lambda_refresh_interval: int | None = None,
        lambda_choice: str = "fixed",
        lambda_horizon: float | None = None,
        double_q: bool = False,
        non_finite: str = "raise",
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        # The Off-On arguments become attributes, the others go to DQN's constructor (OffOnArgumentsMixin)
        super().__init__(**constructor_arguments(locals()))

    def _check_offon_arguments(self) -> None:
        check_positive_integer("buffer_size", self.buffer_size)  # DQN leaves it unchecked (the package's QRDQN does not)
        super()._check_offon_arguments()
        for name, options in (
            ("mc_mixing", MC_MIXING_OPTIONS),
            ("sarsa_target", SARSA_TARGET_OPTIONS),
            ("loss", tuple(LOSS_FUNCTIONS)),
        ):
            check_option(name, getattr(self, name), options)
        if self.lambda_choice != "fixed" and self.mc_mixing != "lambda":
            raise ValueError(
                f"`lambda_choice` {self.lambda_choice!r} chooses the lambda of the lambda-returns: it needs "
                f"`mc_mixing='lambda'`, got {self.mc_mixing!r}"
            )
        if self.lambda_horizon is not None and self.mc_mixing != "lambda":
            raise ValueError(
                "`lambda_horizon` states the lambda of the lambda-returns: it needs `mc_mixing='lambda'`, "
                f"got {self.mc_mixing!r}"
            )

    def _connect_replay_buffer(self) -> None:
        if isinstance(self.replay_buffer, OffOnBufferMixin):
            bootstraps = self.mc_truncation == "bootstrap"
            self.replay_buffer.truncation_value_fn = self._target_state_values if bootstraps else None
            self.replay_buffer.drop_truncated_returns = self.mc_truncation == "drop"
        elif getattr(self, "double_q", False):
            raise ValueError(
                f"`double_q` needs an Off-On replay buffer: with {type(self.replay_buffer).__name__}, OffOnDQN trains as "
                "SB3's DQN does, whose targets have no double Q-learning"
            )
        elif not getattr(self, "_warned_plain_buffer", False):
            self._warned_plain_buffer = True
            warnings.warn(
                f"OffOnDQN: {type(self.replay_buffer).__name__} records no Monte-Carlo returns nor next actions; "
                "training uses Q-learning targets only (plain DQN). Use an OffOnReplayBuffer for the Off-On targets."
            )

    def _online_greedy_actions(self, observations: th.Tensor | dict[str, th.Tensor]) -> th.Tensor:
        """
        argmax_a Q(s, a) of the online network, in evaluation mode, as when it acts: training mode would draw Dropout
        masks into the choice and move BatchNorm's running statistics with next states (SB3's DQN never runs the
        online network on them).
        """
        training = self.q_net.training
        self.q_net.set_training_mode(False)
        try:
            return self.q_net(observations).argmax(dim=1)
        finally:
            self.q_net.set_training_mode(training)

    def _bootstrap(self, observations: th.Tensor | dict[str, th.Tensor]) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """
        What a target bootstraps from at a batch of states s (on the device, under ``no_grad`` at the caller's).

        :param observations: the states, as the networks take them
        :return: Q_target(s, .) of every action; the bootstrap action a*, argmax_a Q_target(s, a) (DQN) or, with
            ``double_q``, argmax_a Q(s, a) of the online network (double Q-learning); and V(s) = Q_target(s, a*)
        """
        q_values_all = self.q_net_target(observations)
        if not self.double_q:
            values, actions = q_values_all.max(dim=1)
            return q_values_all, actions, values
        # The online network picks, the target network evaluates (van Hasselt et al. 2016)
        actions = self._online_greedy_actions(observations)
        return q_values_all, actions, th.gather(q_values_all, dim=1, index=actions.reshape(-1, 1)).reshape(-1)

    def _parameter_list(self) -> list[th.nn.Parameter]:
        """The policy's parameters, whose gradients are clipped: listed once by an ``OffOnDQNPolicy``, else at each call."""
        if isinstance(self.policy, OffOnDQNPolicy):
            return self.policy.parameter_list()
        return list(self.policy.parameters())

    def _target_state_values(self, observations: np.ndarray | dict[str, np.ndarray]) -> np.ndarray:
        """
        V(s) of a batch of unnormalised observations (the bootstrap of truncated episodes): max_a Q_target(s, a), or
        Q_target(s, argmax_a Q(s, a)) with ``double_q``.
        """
        if self._vec_normalize_env is not None:
            observations = self._vec_normalize_env.normalize_obs(observations)
        # Observations come in the replay buffer's layout (a Discrete observation is stored as shape (1,)): convert
        # them as the buffer converts its samples, onto the networks' device
        obs_tensor = obs_as_tensor(observations, self.policy.device)
        with th.no_grad():
            values = self._bootstrap(obs_tensor)[2].cpu().numpy()
        # Q is in the units of the (maybe normalised) rewards it learnt from, the buffer's returns in raw units
        return values * reward_scale(self._vec_normalize_env)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """
        ``gradient_steps`` updates of the Q-network, each on a minibatch of ``batch_size`` transitions.

        SB3's DQN samples, computes the targets and reads the loss back from the device at each step. Here the
        minibatches are gathered and uploaded in chunks of several steps (sampled from the global RNG exactly as SB3
        samples them), the target network's values of a chunk come from one forward pass (it does not change during a
        training call: SB3 updates it between rollout steps), which target each sample gets is decided on the host,
        where its return and next action already are, and the statistics stay on the device until one read at the end.
        Every step's update is the one the per-step loop would make: same samples, same targets, same order.
        """
        self._update_offon_schedules()
        if not isinstance(self.replay_buffer, OffOnBufferMixin):
            super().train(gradient_steps, batch_size)
        # Each kind of target has its loop in its own mixin (coin_flip_targets.py, lambda_training.py)
        elif self.mc_mixing == "lambda":
            self._train_on_lambda_cache(gradient_steps, batch_size)
        else:
            self._train_on_coin_flip_targets(gradient_steps, batch_size)
        self._check_training_loss()

    def _loss_fn(self) -> Any:
        # Looked up at each call, so that a test can swap the function in LOSS_FUNCTIONS
        return LOSS_FUNCTIONS[self.loss]

    def learn(
        self: SelfOffOnDQN,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "OffOnDQN",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfOffOnDQN:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
