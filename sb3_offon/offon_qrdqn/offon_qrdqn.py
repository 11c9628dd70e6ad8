from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from sb3_contrib.qrdqn.policies import CnnPolicy, MlpPolicy, MultiInputPolicy, QRDQNPolicy
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_offon.common.buffers import OffOnBufferMixin
from sb3_offon.common.chunks import ChunkedMinibatchesMixin
from sb3_offon.common.lambda_choice import PER_TRANSITION_CHOICES
from sb3_offon.common.lambda_horizons import sample_horizon_returns
from sb3_offon.common.lambda_refresh import LambdaRefreshMixin
from sb3_offon.common.lambda_returns import LambdaReturnCache
from sb3_offon.common.offon_arguments import OffOnArgumentsMixin, constructor_arguments
from sb3_offon.common.offon_model import check_option
from sb3_offon.common.prioritized_buffers import PrioritizedBufferMixin
from sb3_offon.common.quantile_loss import WeightedQuantileHuberLoss, quantile_huber_loss
from sb3_offon.offon_qrdqn.quantile_lambda_returns import LAMBDA_FORMS, compute_quantile_lambda_returns
from sb3_offon.qrdqn import QRDQN

SelfOffOnQRDQN = TypeVar("SelfOffOnQRDQN", bound="OffOnQRDQN")

# OffOnDQN's target modes, of which OffOnQRDQN has the lambda-returns only; and its losses, of which the quantile critic
# has the (quantile) Huber loss only
SUPPORTED_MC_MIXING = ("lambda",)
SUPPORTED_LOSSES = ("huber",)
PRIORITIZED_NEEDS_CACHE = "`replay_buffer_class`: prioritised replay needs the cache (`lambda_cache=True`)"


class OffOnQRDQN(LambdaRefreshMixin, ChunkedMinibatchesMixin, OffOnArgumentsMixin, QRDQN):
    """
    Off-On QR-DQN: QR-DQN's quantile critic trained towards distributional lambda-returns from the replayed episodes,
    computed as OffOnDQN's lambda-returns are (its default ``mc_mixing="lambda"``), with the target network's quantiles
    in place of its values.

    Paper: Kim, "Deep Reinforcement Learning by Balancing Offline Monte Carlo and Online Temporal Difference Use Based
    on Environment Experiences", Symmetry 12(10):1685, 2020, https://doi.org/10.3390/sym12101685 (delta1 and delta2,
    read as weights); Dabney et al., "Distributional Reinforcement Learning with Quantile Regression", AAAI 2018,
    https://arxiv.org/abs/1710.10044 (the critic); Daley & Amato, "Reconciling lambda-Returns with Experience Replay",
    NeurIPS 2019 (the cached returns).

    A drop-in for :class:`sb3_offon.qrdqn.QRDQN` (sb3-contrib's QR-DQN with a faster loss): its policies, arguments and
    defaults, plus OffOnDQN's lambda-mode arguments with OffOnDQN's names and defaults (lambda = delta1 = 0.9, Peng's
    Q(lambda) with delta2 = 0), so that moving between OffOnDQN and OffOnQRDQN changes one word.

    The target of a transition t is the law of its lambda-return: the mixture over horizons k of the k-step laws
    r_t + ... + gamma^(k-1) r_(t+k-1) + gamma^k Z(s_(t+k), a*), with weights (1 - lam) lam^(k-1), the trace cut after
    non-greedy actions by the delta2 weight exactly as in OffOnDQN (greedy: the argmax of the quantiles' mean, the
    target network's, or the online network's with ``double_q``); a terminated episode's remaining weight on the Dirac
    at its Monte-Carlo return; a truncated one's on Z(s_T) (``mc_truncation`` ``"bootstrap"`` and ``"drop"``) or on 0
    (``"terminal"``); n-step windows as in OffOnDQN (``n_steps``). Equivalently, the backward recursion
    Z^lam_t = r_t + gamma [(1 - lam c) Z(s_(t+1)) (+) lam c Z^lam_(t+1)]. lambda = 0 gives QR-DQN's own target (n-step
    QR-DQN's with ``n_steps``), lambda = 1 without cuts a terminated episode's Monte-Carlo return.

    The cache holds N target atoms per computed return (N = ``n_quantiles``), computed at each refresh from one batched
    pass of the target network, as DQN(lambda) does, and the minibatches are drawn from it; the refresh, its blocks
    and the minibatches are OffOnDQN's (see ``mc_mixing="lambda"`` there): no target network pass per gradient step.
    ``lambda_form`` says how the law becomes N atoms (:mod:`sb3_offon.offon_qrdqn.quantile_lambda_returns`):

    - ``"sampled"`` (default): a horizon is drawn per transition at each refresh from the weights above, and the target
      is that horizon's k-step law; the quantile loss being linear in the target law, this is an unbiased draw of the
      mixture's loss, with no projection, at the cost of vectorised NumPy work only;
    - ``"projected"``: the backward recursion, each mixture of 2N weighted atoms projected back onto N atoms (the
      mixture's quantiles at tau_i = (2i - 1) / 2N, the W1 projection); deterministic, but projecting projected laws,
      and a loop over each block's steps.

    The default is the sampled form: exact in expectation and cheaper. A setup check on tuning seeds, its rule written
    before its runs, found the two level (mean normalised AUC 0.928 against 0.924 over CartPole-v1 and Acrobot-v1,
    seeds 0-1) and kept the sampled form (``results/qr_lambda_form/README.md``); the projected form stays as an option.

    ``lambda_cache=False`` trains without the cache: each training call draws its minibatches uniformly from the whole
    buffer, as QR-DQN does, and each sample gets a horizon drawn from the lambda-return's weights, its target that
    horizon's law from the target network of the moment (:mod:`sb3_offon.common.lambda_horizons`). A transition gets a
    fresh horizon each time it is sampled, the newest transitions are trained on as soon as they are stored, and the
    cost per gradient step is n-step QR-DQN's: one target row per sample. It needs Peng's Q(lambda) (delta2 = 0) and
    the sampled form; ``lambda_block_size`` is then the longest horizon drawn, and prioritised replay is not supported.
    The targets of a training call's gradient steps are computed together, at its start (the target network does not
    change within a call; with ``double_q``, the online network's argmax is that of the call's start, as the cache's is
    that of the refresh). With lambda = 0 it is n-step QR-DQN (``n_steps``) on the same samples.

    What OffOnQRDQN does not have: OffOnDQN's coin-flip modes (``mc_mixing`` other than ``"lambda"``), the squared error
    (``loss="mse"``) and dueling networks (``policy_kwargs=dict(dueling=True)``), each a ``ValueError``;
    ``sarsa_target`` is accepted and plays no part, as in OffOnDQN's lambda mode. The buffer is an Off-On buffer (its
    episode bookkeeping and recorded next actions are what the trace needs); another ``replay_buffer_class`` is a
    ``ValueError``. Unlike OffOnDQN's, its Monte-Carlo returns are not bootstrapped when an episode is cut (the
    lambda-returns never read them): ``mc_truncation`` acts at the refresh.

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, ...)
    :param env: The environment to learn from (if registered in Gym, can be str)
    :param learning_rate: The learning rate, it can be a function of the current progress remaining (from 1 to 0)
    :param buffer_size: size of the replay buffer
    :param learning_starts: how many steps of the model to collect transitions for before learning starts
    :param batch_size: Minibatch size for each gradient update
    :param tau: the soft update coefficient ("Polyak update", between 0 and 1) default 1 for hard update
    :param gamma: the discount factor
    :param train_freq: Update the model every ``train_freq`` steps. Alternatively pass a tuple of frequency and unit
        like ``(5, "step")`` or ``(2, "episode")``.
    :param gradient_steps: How many gradient steps to do after each rollout (see ``train_freq`` and ``n_episodes_rollout``)
        Set to ``-1`` means to do as many gradient steps as steps done in the environment during the rollout.
    :param replay_buffer_class: Replay buffer class to use: an Off-On buffer (None: the one matching the observation
        space and ``n_steps``)
    :param replay_buffer_kwargs: Keyword arguments to pass to the replay buffer on creation (``gamma`` and ``n_steps`` are
        the model's, as in OffOnDQN)
    :param optimize_memory_usage: Enable a memory efficient variant of the replay buffer at a cost of more complexity
        (as in OffOnDQN: a time-limit truncation is then taken for a termination)
    :param n_steps: the steps of the lambda-return are n-step windows (lambda = 0: n-step QR-DQN's target)
    :param target_update_interval: update the target network every ``target_update_interval`` environment steps.
    :param exploration_fraction: fraction of entire training period over which the exploration rate is reduced
    :param exploration_initial_eps: initial value of random action probability
    :param exploration_final_eps: final value of random action probability
    :param max_grad_norm: The maximum value for the gradient clipping (if None, no clipping)
    :param mc_initial_prob: initial lambda (delta1): how far the target looks ahead. Default 0.9
    :param mc_final_prob: final lambda. Default 0.9
    :param mc_fraction: fraction of the training period over which lambda goes from initial to final
    :param qlearning_initial_prob: initial delta2: the trace weight after a non-greedy action is 1 - delta2. Default 0.0,
        Peng's Q(lambda); 1.0 is Watkins's
    :param qlearning_final_prob: final delta2. Default 0.0
    :param qlearning_fraction: fraction of the training period over which delta2 goes from initial to final
    :param mc_mixing: ``"lambda"``, the only mode (OffOnDQN's name, accepted so that its arguments carry over)
    :param sarsa_target: accepted for OffOnDQN's arguments; plays no part
    :param mc_truncation: after a time-limit truncation, the trace ends on Z(s_T) (``"bootstrap"``, ``"drop"``) or on 0
        (``"terminal"``)
    :param loss: ``"huber"``, the quantile Huber loss (QR-DQN's), the only one
    :param lambda_block_size: the number of consecutive stored transitions whose lambda-returns are computed together
    :param lambda_refresh_interval: recompute the cached lambda-returns every this many env steps; None (default):
        whenever the target network is updated
    :param double_q: the online network picks the bootstrap action (the argmax of its quantiles' mean), the target
        network's quantiles at that action are the bootstrap law; the trace-cut test uses that action too
    :param lambda_form: ``"sampled"`` (default) or ``"projected"`` (see above)
    :param lambda_cache: True (default): train on the cached lambda-returns of each refresh; False: draw a horizon per
        sample at each training call, from the whole buffer (see above)
    :param lambda_choice: ``"fixed"`` (default), lambda is delta1 for every transition; ``"median"``, a lambda per
        transition chosen at each refresh from the data (DQN(lambda)'s dynamic return, applied to the mean of the
        target atoms: :mod:`sb3_offon.common.lambda_choice`), delta1 then unused; the transition's target is its chosen
        lambda's sampled horizon (the cache and the sampled form only); ``"autocorrelation"``, one lambda per refresh, the
        lag-one correlation of the TD errors of the atoms' mean along the traces, clipped to [0, 1] (delta1 where it
        cannot be measured; the cache only). The chosen lambdas' mean (``train/lambda``) and, per transition, their
        standard deviation (``train/lambda_std``) are logged
    :param lambda_horizon: lambda stated as a horizon in env steps: None (default), lambda is delta1's schedule; h,
        lambda for the whole run is the one whose lambda-return contracts like an h-step return with the model's
        ``gamma``, lambda_h = (1 - gamma^(h-1)) / (1 - gamma^h) (:func:`sb3_offon.lambda_for_horizon`; 3: 0.670 and
        5: 0.804 at gamma 0.99), over n-step windows that of h / n windows with discount gamma^n (h = ``n_steps``:
        lambda 0). It takes the place of ``mc_initial_prob`` and ``mc_final_prob``, which stay at their defaults
    :param non_finite: what a non-finite reward does: ``"raise"`` (default) a ``NonFiniteError`` naming the env and step,
        nothing of that step stored; ``"skip"`` a warning, the step's transitions not stored and the running episodes
        cut there as truncations. A non-finite loss always raises (:mod:`sb3_offon.common.non_finite`)
    :param stats_window_size: Window size for the rollout logging, specifying the number of episodes to average
        the reported success rate, mean episode length, and mean reward over
    :param tensorboard_log: the log location for tensorboard (if None, no logging)
    :param policy_kwargs: additional arguments to be passed to the policy on creation (``n_quantiles`` among them)
    :param verbose: the verbosity level: 0 no output, 1 info, 2 debug
    :param seed: Seed for the pseudo random generators, including the generator of the sampled horizons
    :param device: Device (cpu, cuda, ...) on which the code should be run.
        Setting it to auto, the code will be run on the GPU if possible.
    :param _init_setup_model: Whether or not to build the network at the creation of the instance
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": MlpPolicy,
        "CnnPolicy": CnnPolicy,
        "MultiInputPolicy": MultiInputPolicy,
    }
    # OffOnDQN's Off-On arguments and OffOnQRDQN's own, set as attributes by OffOnArgumentsMixin
    offon_parameters: ClassVar[tuple[str, ...]] = (*OffOnArgumentsMixin.offon_parameters, "lambda_form", "lambda_cache")
    lambda_form: str
    lambda_cache: bool

    def __init__(
        self,
        policy: str | type[QRDQNPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 5e-5,
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
        exploration_fraction: float = 0.005,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.01,
        max_grad_norm: float | None = None,
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
        double_q: bool = False,
        lambda_form: str = "sampled",
        lambda_cache: bool = True,
        lambda_choice: str = "fixed",
        lambda_horizon: float | None = None,
        non_finite: str = "raise",
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        # The Off-On arguments become attributes, the others go to QRDQN's constructor (OffOnArgumentsMixin)
        super().__init__(**constructor_arguments(locals()))

    def _check_offon_arguments(self) -> None:
        super()._check_offon_arguments()
        for name, options, what in (
            ("mc_mixing", SUPPORTED_MC_MIXING, "OffOnDQN's coin-flip modes are not supported by OffOnQRDQN"),
            ("loss", SUPPORTED_LOSSES, "OffOnQRDQN's loss is the quantile Huber loss"),
            ("lambda_form", LAMBDA_FORMS, ""),
        ):
            try:
                check_option(name, getattr(self, name), options)
            except ValueError as error:
                raise ValueError(f"{error}{f' ({what})' if what else ''}") from None
        self._check_lambda_cache()
        if self.lambda_choice != "fixed" and not self.lambda_cache:
            raise ValueError(
                f"`lambda_choice` {self.lambda_choice!r} chooses lambda at each refresh of the cache: it needs "
                "`lambda_cache=True`"
            )
        if self.lambda_choice in PER_TRANSITION_CHOICES and self.lambda_form != "sampled":
            raise ValueError(
                f"`lambda_choice` {self.lambda_choice!r} chooses a lambda per transition and draws its horizon: it needs "
                "`lambda_form='sampled'`"
            )
        if not isinstance(self.sarsa_target, str):
            raise ValueError(f"`sarsa_target` must be a string, got {self.sarsa_target!r}")
        if "dueling" in (self.policy_kwargs or {}):
            # QR-DQN's policy would fail on it with a TypeError that does not say what to do
            raise ValueError(
                "`policy_kwargs['dueling']`: dueling networks are OffOnDQN's only; OffOnQRDQN's quantile network is "
                "QR-DQN's (remove the key)"
            )

    def _check_lambda_cache(self) -> None:
        """What training without the cache (``lambda_cache=False``) needs."""
        # A model saved before lambda_cache existed loads with the constructor's default (load() runs __init__ first):
        # the cache, as it trained
        if not isinstance(self.lambda_cache, (bool, np.bool_)):
            raise ValueError(f"`lambda_cache` must be True or False, got {self.lambda_cache!r}")
        if self.lambda_cache:
            return
        if self.lambda_form != "sampled":
            raise ValueError("`lambda_form`: without the cache (`lambda_cache=False`) the horizons are sampled; use 'sampled'")
        if self.qlearning_initial_prob != 0.0 or self.qlearning_final_prob != 0.0:
            raise ValueError(
                "`qlearning_initial_prob`, `qlearning_final_prob`: without the cache (`lambda_cache=False`) the trace is "
                "Peng's, never cut (delta2 = 0)"
            )
        buffer_class = self.replay_buffer_class
        if isinstance(buffer_class, type) and issubclass(buffer_class, PrioritizedBufferMixin):
            raise ValueError(PRIORITIZED_NEEDS_CACHE)

    def _connect_replay_buffer(self) -> None:
        # Also run by load_replay_buffer: a prioritised buffer loaded into a model without the cache would bring the
        # cache back in silence (the prioritised draw is the cache's)
        if not self.lambda_cache and isinstance(self.replay_buffer, PrioritizedBufferMixin):
            raise ValueError(PRIORITIZED_NEEDS_CACHE)
        if not isinstance(self.replay_buffer, OffOnBufferMixin):
            raise ValueError(
                f"`replay_buffer_class`: OffOnQRDQN needs an Off-On replay buffer (its episode ends and next actions make "
                f"the lambda-returns), got {type(self.replay_buffer).__name__}"
            )
        # The buffer's Monte-Carlo returns are never read here: no bootstrap pass when an episode is cut
        self.replay_buffer.truncation_value_fn = None
        self.replay_buffer.drop_truncated_returns = False

    def _bootstrap_quantiles(self, observations: th.Tensor | dict[str, th.Tensor]) -> tuple[th.Tensor, th.Tensor]:
        """
        The bootstrap law at a batch of states s (on the device, under ``no_grad`` at the caller's): the target network's
        quantiles at a*, shaped (batch, N), and a*: the argmax of the target network's quantile means, or, with
        ``double_q``, of the online network's (in evaluation mode, as when it acts).
        """
        quantiles = self.quantile_net_target(observations)  # (batch, N, actions)
        if self.double_q:
            training = self.quantile_net.training
            self.quantile_net.set_training_mode(False)
            try:
                actions = self.quantile_net(observations).mean(dim=1).argmax(dim=1)
            finally:
                self.quantile_net.set_training_mode(training)
        else:
            actions = quantiles.mean(dim=1).argmax(dim=1)
        index = actions.reshape(-1, 1, 1).expand(-1, quantiles.shape[1], 1)
        return quantiles.gather(dim=2, index=index).squeeze(dim=2), actions

    def _target_quantiles_and_actions(self, observations: np.ndarray | dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Z_target(s, a*) as (batch, N) and a*, for a batch of (normalised) observations, read back to the host once."""
        outputs = self._forward_in_chunks(observations, self._bootstrap_quantiles)
        if not outputs:
            return np.zeros((0, self.n_quantiles), dtype=np.float32), np.zeros(0, dtype=np.int64)
        quantiles, actions = outputs
        # One read-back for both (an action index is exact in float32 up to 2**24 actions)
        both = th.cat([quantiles, actions.to(quantiles.dtype)[:, None]], dim=1).cpu().numpy()
        return both[:, :-1], both[:, -1].astype(np.int64)

    def _compute_lambda_cache(self, n_wanted: int, key: int) -> LambdaReturnCache:
        assert isinstance(self.replay_buffer, OffOnBufferMixin)
        return compute_quantile_lambda_returns(
            self.replay_buffer,
            self._target_quantiles_and_actions,
            n_wanted=n_wanted,
            block_size=self.lambda_block_size,
            gamma=self.gamma,
            lam=self.mc_prob,
            qlearning_prob=self.qlearning_prob,
            cut_is_terminal=self.mc_truncation == "terminal",
            key=key,
            form=self.lambda_form,
            rng=self.target_rng,
            env=self._vec_normalize_env,
            choice=self.lambda_choice,
        )

    def _draw_lambda_entries(self, n_samples: int) -> tuple[LambdaReturnCache, np.ndarray]:
        """With the cache, its entries (refreshed first if due); without it, ``n_samples`` fresh targets, in order."""
        if self.lambda_cache:
            return super()._draw_lambda_entries(n_samples)
        return self._horizon_targets(n_samples), np.arange(n_samples)

    def _horizon_targets(self, n_samples: int) -> LambdaReturnCache:
        """
        ``n_samples`` transitions drawn from the whole buffer, each with a drawn horizon's target law, computed with
        the target network of the moment and left on the device (no read-back), in the cache's layout.
        """
        assert isinstance(self.replay_buffer, OffOnBufferMixin)
        samples = sample_horizon_returns(
            self.replay_buffer,
            n_samples,
            batch_size=self.batch_size,
            lam=self.mc_prob,
            longest=self.lambda_block_size,
            gamma=self.gamma,
            cut_is_terminal=self.mc_truncation == "terminal",
            rng=self.target_rng,
            env=self._vec_normalize_env,
        )
        quantiles = self._forward_in_chunks(samples.next_observations, self._bootstrap_quantiles)[0]  # (n, N)
        rewards = self._to_device(samples.rewards.astype(np.float32).reshape(-1, 1))
        discounts = self._to_device(samples.discounts.astype(np.float32).reshape(-1, 1))
        self.logger.record("train/mean_horizon", float(samples.horizons.mean()))
        return LambdaReturnCache(
            slots=samples.slots,
            envs=samples.envs,
            added_at=samples.added_at,
            returns=rewards + discounts * quantiles,
            key=self._lambda_refresh_key(),
            lam=self.mc_prob,
            qlearning_prob=0.0,
            trace_cut_fraction=0.0,
        )

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """
        ``gradient_steps`` updates of the quantile network towards the cached distributional lambda-returns (refreshed
        first if due; with ``lambda_cache=False``, towards fresh targets of drawn horizons), the minibatches gathered
        and uploaded in chunks, the loss read back once at the end.
        """
        assert isinstance(self.replay_buffer, OffOnBufferMixin)
        self._update_offon_schedules()
        self._train_on_lambda_cache(gradient_steps, batch_size)
        self._check_training_loss()

    def _parameter_list(self) -> list[th.nn.Parameter]:
        """The policy's parameters, whose gradients are clipped (with ``max_grad_norm``)."""
        return list(self.policy.parameters())

    def _lambda_chunk_tensors(
        self, actions: np.ndarray, returns: np.ndarray | th.Tensor, weights: np.ndarray | None
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        """
        A chunk's actions repeated over the quantiles (to gather them), its N target atoms per sample (already on the
        device without the cache), its weights.
        """
        actions_tensor = self._to_device(actions.reshape(-1, 1, 1)).long().expand(-1, self.n_quantiles, 1)
        weights_tensor = None if weights is None else self._to_device(weights)
        targets = returns if isinstance(returns, th.Tensor) else self._to_device(returns)
        return actions_tensor, targets, weights_tensor

    def _lambda_step_loss(
        self, observations: Any, actions: th.Tensor, targets: th.Tensor, weights: th.Tensor | None
    ) -> tuple[th.Tensor, th.Tensor | None]:
        """
        The quantile Huber loss of the taken actions' quantiles against the target atoms; with importance weights, each
        sample's loss is also its error, its new priority (as Rainbow's per-sample KL).
        """
        current_quantiles = th.gather(self.quantile_net(observations), dim=2, index=actions).squeeze(dim=2)
        if weights is None:
            return quantile_huber_loss(current_quantiles, targets, sum_over_quantiles=True), None
        loss, per_sample = WeightedQuantileHuberLoss.apply(current_quantiles, targets, weights)
        return loss, per_sample

    def learn(
        self: SelfOffOnQRDQN,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "OffOnQRDQN",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfOffOnQRDQN:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
