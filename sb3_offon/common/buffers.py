"""Replay buffers that keep, next to each transition, its Monte-Carlo return and the action taken next."""

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer, NStepReplayBuffer, ReplayBuffer
from stable_baselines3.common.type_aliases import TensorDict
from stable_baselines3.common.vec_env import VecNormalize

from sb3_offon.common.stored_rows import StoredRows

# Maps the (unnormalised) final observations of truncated episodes, batched, to their state values
# max_a Q_target(s_T, a). Set by OffOnDQN; never pickled with the buffer.
TruncationValueFn = Callable[[np.ndarray | dict[str, np.ndarray]], np.ndarray]

UNKNOWN_ACTION = -1


class OffOnReplayBufferSamples(NamedTuple):
    """SB3's ``ReplayBufferSamples`` plus the recorded next action (-1: unknown) and Monte-Carlo return (NaN: unknown)."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor | None
    next_actions: th.Tensor
    mc_returns: th.Tensor


class OffOnDictReplayBufferSamples(NamedTuple):
    """SB3's ``DictReplayBufferSamples`` plus the recorded next action and Monte-Carlo return."""

    observations: TensorDict
    actions: th.Tensor
    next_observations: TensorDict
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor | None
    next_actions: th.Tensor
    mc_returns: th.Tensor


class OffOnMinibatches(NamedTuple):
    """
    A training call's minibatches, gathered at once: ``samples`` holds them one after the other (rows
    ``[k * batch_size, (k + 1) * batch_size)`` are the k-th), on the buffer's device. ``next_actions`` and
    ``mc_returns`` are the same columns as in ``samples``, as the NumPy arrays they were made from, so that the target
    choice is decided on the host without reading anything back from the device.
    """

    samples: "OffOnReplayBufferSamples | OffOnDictReplayBufferSamples"
    next_actions: np.ndarray
    mc_returns: np.ndarray


def reward_scale(env: VecNormalize | None) -> float:
    """The factor VecNormalize divides rewards by (1 without reward normalisation), before its clip."""
    if env is None or not env.norm_reward:
        return 1.0
    return float(np.sqrt(env.ret_rms.var + env.epsilon))


def discounted_returns(rewards: np.ndarray, gamma: float, tail_value: float = 0.0) -> np.ndarray:
    """
    G_t = r_t + gamma * G_{t+1} for every step of one episode, computed backwards in one vectorised pass.

    :param rewards: the episode's rewards r_0 .. r_{T-1}
    :param gamma: the discount factor
    :param tail_value: the value of the state after the last step (0 for a terminated episode)
    :return: float64 array of G_0 .. G_{T-1}
    """
    # Imported here: scipy.signal takes seconds to import, which every CLI process would pay up front
    from scipy.signal import lfilter

    # lfilter runs y[t] = x[t] + gamma * y[t-1]; on the reversed rewards, with the tail as the first element, that is
    # the backward recursion. It is exact in float64 for any length, unlike the gamma^-t cumulative-sum trick.
    reversed_with_tail = np.concatenate(([tail_value], rewards[::-1].astype(np.float64)))
    return lfilter([1.0], [1.0, -gamma], reversed_with_tail)[:0:-1]


class OffOnBufferMixin:
    """
    Episode bookkeeping shared by the Off-On replay buffers: the episode buffer Omega of the paper, and next actions.

    Omega holds, per env ``e``, where its running episode started. When the episode ends, its returns G_t are
    computed from the rewards in the replay buffer and written into ``mc_returns[:, e]`` at the slots it still holds:
    G_t needs only the rewards from t on, and the slots an episode still holds are its latest ones, so an episode
    longer than the buffer gets exact returns too, without a reward log of its own.
    ``next_actions[t, e]`` is the action taken at s_{t+1} in the same episode, for the Sarsa target.
    Overwriting a slot resets both to unknown (NaN, -1).

    Time-limit truncation: the return after the last step is ``truncation_value_fn(final_obs)`` when that is set
    (OffOnDQN sets it for ``mc_truncation="bootstrap"``), else 0 (``"terminal"``). With ``drop_truncated_returns``
    (``"drop"``), a truncated episode's returns stay unknown, so that every known return is an observed one.

    :param gamma: the discount factor of the Monte-Carlo returns (OffOnDQN passes its own)
    """

    # Attributes of SB3's ReplayBuffer, declared for type checkers
    buffer_size: int
    n_envs: int
    pos: int
    full: bool
    optimize_memory_usage: bool
    handle_timeout_termination: bool
    observations: Any
    dones: np.ndarray
    timeouts: np.ndarray
    next_observations: Any
    rewards: np.ndarray
    device: th.device
    # The steps each transition's TD target spans: 1 here, SB3's NStepReplayBuffer sets its own ``n_steps`` per instance
    n_steps: int = 1

    def _init_offon(self, gamma: float) -> None:
        self.gamma = gamma
        self.truncation_value_fn: TruncationValueFn | None = None
        self.drop_truncated_returns = False
        self.mc_returns = np.full((self.buffer_size, self.n_envs), np.nan, dtype=np.float32)
        self.next_actions = np.full((self.buffer_size, self.n_envs), UNKNOWN_ACTION, dtype=np.int64)
        self._reset_episodes()

    def _reset_episodes(self) -> None:
        # Number of add() calls so far: the absolute index of the next transition (its slot is that modulo buffer_size)
        self._n_adds = 0
        # Omega: per env, the absolute index of the running episode's first transition (_n_adds: none running yet)
        self.episode_starts = np.zeros(self.n_envs, dtype=np.int64)
        # Episodes cut by end_open_episodes whose last transition (slot, envs) the next add() marks as a truncation
        self._cuts_to_mark: tuple[int, np.ndarray] | None = None

    @property
    def episode_lengths(self) -> np.ndarray:
        """Per env, the number of transitions of its running episode (0: none running)."""
        return self._n_adds - self.episode_starts

    def reset(self) -> None:
        super().reset()  # type: ignore[misc]
        self.mc_returns.fill(np.nan)
        self.next_actions.fill(UNKNOWN_ACTION)
        self._reset_episodes()

    def __getstate__(self) -> dict[str, Any]:
        # The value function points at the model: pickling it would save the model inside the buffer
        state = self.__dict__.copy()
        state["truncation_value_fn"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        if "_n_adds" not in state:
            # Development snapshots before the episode bookkeeping by add count (commit 57f9655) kept other fields
            raise ValueError(
                f"This {type(self).__name__} was pickled by an sb3-offon older than its episode bookkeeping and cannot be "
                "loaded; train a fresh buffer (the model itself loads)"
            )
        # Buffers pickled before mc_truncation="drop" existed bootstrapped or cut their truncations: they keep doing so
        state.setdefault("drop_truncated_returns", False)
        state.setdefault("_cuts_to_mark", None)
        self.__dict__.update(state)

    def add(
        self,
        obs: Any,
        next_obs: Any,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        if self._cuts_to_mark is not None:
            slot, envs = self._cuts_to_mark
            self.timeouts[slot, envs] = True
            self.dones[slot, envs] = True
            self._cuts_to_mark = None
        # This action was taken at the next state of each running episode's previous transition
        action_ids = np.asarray(action).reshape(self.n_envs)
        running = self.episode_starts < self._n_adds
        np.copyto(self.next_actions[(self.pos - 1) % self.buffer_size], action_ids, where=running)
        # The slot about to be overwritten forgets what it knew about its old transition
        self.mc_returns[self.pos] = np.nan
        self.next_actions[self.pos] = UNKNOWN_ACTION

        super().add(obs, next_obs, action, reward, done, infos)  # type: ignore[misc]

        self._n_adds += 1
        if np.count_nonzero(done):
            done_envs = np.flatnonzero(done)
            truncated = np.array([bool(infos[env].get("TimeLimit.truncated", False)) for env in done_envs], dtype=bool)
            for env in done_envs[~truncated]:
                self._finish_episode(int(env), 0.0)
            if truncated.any():
                self._end_truncated(done_envs[truncated], next_obs)

    def _end_truncated(self, env_indices: np.ndarray, final_observations: Any) -> None:
        """
        Close the given envs' episodes, cut (by a time limit or a reset) at their ``final_observations`` (a batch of
        all envs' observations): their returns are bootstrapped from there, or left unknown with
        ``drop_truncated_returns``.
        """
        if self.drop_truncated_returns:
            self.episode_starts[env_indices] = self._n_adds
            return
        tails = self._state_values(final_observations, env_indices)
        for env, tail in zip(env_indices, tails, strict=True):
            self._finish_episode(int(env), float(tail))

    def _state_values(self, observations: Any, env_indices: np.ndarray) -> np.ndarray:
        """Bootstrap values of the given envs' final observations (taken from a batch of all envs' observations)."""
        if self.truncation_value_fn is None:
            return np.zeros(len(env_indices))
        if isinstance(observations, dict):
            selected = {key: np.asarray(value)[env_indices] for key, value in observations.items()}
        else:
            selected = np.asarray(observations)[env_indices]
        return np.asarray(self.truncation_value_fn(selected), dtype=np.float64).reshape(len(env_indices))

    def _finish_episode(self, env: int, tail_value: float) -> None:
        """Write the returns of env's episode, which ended with the latest add(), into the slots it still holds."""
        kept = min(self._n_adds - int(self.episode_starts[env]), self.buffer_size)
        slots = np.arange(self._n_adds - kept, self._n_adds) % self.buffer_size
        self.mc_returns[slots, env] = discounted_returns(self.rewards[slots, env], self.gamma, tail_value)
        self.episode_starts[env] = self._n_adds

    def end_open_episodes(self) -> None:
        """
        End every running episode as truncated at its last stored next observation.

        Called when the env is reset outside an episode end (a new ``learn()`` call), so that an episode that was cut
        off gets its returns, bootstrapped as any time-limit truncation (or left unknown, as any truncation, with
        ``drop_truncated_returns``), and does not chain into the next one. Its last transition is marked done and
        timed out, as SB3 stores a time-limit truncation, so that an n-step target's window (SB3's
        ``NStepReplayBuffer``) stops there too instead of running on into the next episode's rewards: marked by the
        next ``add()``, the first transition it could chain into, so that until then the buffer holds what was stored
        (SB3's ``load_replay_buffer`` gives back a buffer's flags as they were saved).

        With ``optimize_memory_usage`` (which SB3 allows only without ``handle_timeout_termination``) a cut cannot be
        stored as a truncation: the flags are left as they are (SB3 marks the transition done when
        ``reset_num_timesteps``), and the last transition's next observation is the slot the next episode's first
        observation overwrites, so its one-step and λ targets bootstrap from that observation, as SB3's DQN's do.
        """
        last = (self._n_adds - 1) % self.buffer_size
        running = np.flatnonzero(self.episode_starts < self._n_adds)
        if len(running) == 0:
            return
        if self.handle_timeout_termination:
            self._cuts_to_mark = (last, running)
        self._end_truncated(running, self._stored_next_observations(last))

    def _stored_next_observations(self, slot: int) -> Any:
        if self.optimize_memory_usage:
            return self.observations[(slot + 1) % self.buffer_size]
        if isinstance(self.next_observations, dict):
            return {key: value[slot] for key, value in self.next_observations.items()}
        return self.next_observations[slot]

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> Any:
        return self._gather(batch_inds, env).samples

    def sample_minibatches(self, n_batches: int, batch_size: int, env: VecNormalize | None = None) -> OffOnMinibatches:
        """
        ``n_batches`` minibatches of ``batch_size`` transitions, the same as ``n_batches`` calls of ``sample()`` would
        give (the global RNG is consumed in the same order, so it ends where SB3's per-step sampling leaves it), made
        into tensors at once: one upload per column instead of one per column and minibatch.

        :param n_batches: the number of minibatches (a training call's gradient steps)
        :param batch_size: the number of transitions in each
        :param env: VecNormalize env to normalise the observations and rewards with (as for ``sample()``)
        :return: the minibatches one after the other, with host copies of the return and next-action columns
        """
        if self.n_envs == 1:
            # With one env, SB3's sample() draws the slots and nothing else (the env-index draw over one value leaves
            # the RNG alone): drawing all the slots first, then gathering once, gives the same samples
            batch_inds = np.concatenate([self._draw_slots(batch_size) for _ in range(n_batches)])
            return self._gather(batch_inds, env)
        # With several envs, SB3 draws each minibatch's env indices inside its gather, between two minibatches' slot
        # draws: gathering per minibatch keeps that order, and only the upload is batched
        parts = [self._gather(self._draw_slots(batch_size), env, upload=False) for _ in range(n_batches)]
        return self._upload(
            _concatenate([part.samples for part in parts]),
            np.concatenate([part.next_actions for part in parts]),
            np.concatenate([part.mc_returns for part in parts]),
        )

    def _draw_slots(self, batch_size: int) -> np.ndarray:
        """The slot indices that SB3's ``sample()`` draws (``ReplayBuffer.sample``: not the newest slot, whose next
        observation is not stored yet, with ``optimize_memory_usage``; ``BaseBuffer.sample`` otherwise)."""
        if self.optimize_memory_usage and self.full:
            return (np.random.randint(1, self.buffer_size, size=batch_size) + self.pos) % self.buffer_size
        upper_bound = self.buffer_size if self.full else self.pos
        return np.random.randint(0, upper_bound, size=batch_size)

    def _gather(self, batch_inds: np.ndarray, env: VecNormalize | None = None, upload: bool = True) -> OffOnMinibatches:
        """
        SB3's samples at ``batch_inds`` (its ``_get_samples``, which also draws the env indices), plus each sample's next
        action and Monte-Carlo return.

        :param upload: False: leave every column as a NumPy array (to be concatenated with others, then uploaded)
        """
        # SB3 draws each sample's env index inside _get_samples and does not return it. With one env it is 0. With
        # several, replaying that one draw from the same global RNG state recovers the indices, so SB3's sampling code
        # is reused as it is. The replay consumes the RNG exactly as SB3's draw did, so the global RNG ends where plain
        # SB3 would leave it (which the bit-identity with DQN relies on). Saving and restoring the state costs about
        # 0.2 ms, hence the shortcut for one env.
        if not upload:
            self.to_torch = _keep_numpy  # type: ignore[method-assign,assignment]
        try:
            if self.n_envs == 1:
                samples = super()._get_samples(batch_inds, env)  # type: ignore[misc]
                env_indices = np.zeros(len(batch_inds), dtype=np.int64)
            else:
                rng_state = np.random.get_state(legacy=False)
                samples = super()._get_samples(batch_inds, env)  # type: ignore[misc]
                np.random.set_state(rng_state)
                env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        finally:
            if not upload:
                del self.to_torch  # back to the class's method
        next_actions = self._sarsa_next_actions(batch_inds, env_indices).reshape(-1, 1)
        mc_returns = self.mc_returns[batch_inds, env_indices].reshape(-1, 1)
        if env is not None:
            # Stored in raw reward units, like the rewards, and scaled like them (the per-reward clip aside)
            mc_returns /= reward_scale(env)
        if not upload:
            return OffOnMinibatches(samples, next_actions, mc_returns)
        return self._upload(samples, next_actions, mc_returns)

    def _upload(self, samples: Any, next_actions: np.ndarray, mc_returns: np.ndarray) -> OffOnMinibatches:
        """Put the columns that are still NumPy arrays on the device, as Off-On samples."""
        sample_class = OffOnDictReplayBufferSamples if isinstance(samples.observations, dict) else OffOnReplayBufferSamples
        columns = {name: _to_device(value, self.to_torch) for name, value in samples._asdict().items()}
        return OffOnMinibatches(
            sample_class(**columns, next_actions=self.to_torch(next_actions), mc_returns=self.to_torch(mc_returns)),
            next_actions,
            mc_returns,
        )

    def to_torch(self, array: np.ndarray, copy: bool = True) -> th.Tensor:
        """
        A tensor on the buffer's device that shares memory with ``array`` on the CPU, whatever ``copy`` says.

        SB3's ``to_torch`` copies each sampled array. The arrays that ``_get_samples`` passes (SB3's and ours) are fresh
        results of fancy indexing or arithmetic that nothing else holds, so sharing is safe (a test checks that samples
        do not change with the buffer), and saves about 4 microseconds per array: per gradient step, about as much as
        the return and next-action bookkeeping adds to sampling.

        :param array: a freshly made array
        :param copy: ignored (see above)
        :return: the tensor
        """
        return th.from_numpy(array).to(self.device)

    # --- access by (slot, env) for the lambda-returns of OffOnDQN's mc_mixing="lambda" ---------------------------

    def chronology(self) -> tuple[int, int, int]:
        """
        Where the stored transitions are, in the order they were added (the same for every env column).

        :return: ``(oldest, n_stored, first)``: the slot of the oldest transition, the number of transitions per env,
            and the chronological index of the first one that can be trained on (1 with ``optimize_memory_usage`` on a
            full buffer, where the oldest slot's observation was overwritten by the newest's next observation, else 0).
            Chronological index ``j`` is slot ``(oldest + j) % buffer_size`` and the ``(_n_adds - n_stored + j)``-th
            transition ever added.
        """
        n_stored = self.buffer_size if self.full else self.pos
        oldest = self.pos if self.full else 0
        first = 1 if self.optimize_memory_usage and self.full else 0
        return oldest, n_stored, first

    def holds_transition(self, added_at: np.ndarray) -> np.ndarray:
        """Whether the transitions added as the ``added_at``-th (absolute add indices) are still stored and usable."""
        kept = self.buffer_size - (1 if self.optimize_memory_usage else 0)
        return self._n_adds - added_at <= kept

    def lambda_inputs(
        self,
        slots: np.ndarray,
        envs: np.ndarray,
        gamma: float,
        env: VecNormalize | None = None,
        lengths: np.ndarray | None = None,
    ) -> dict[str, Any]:
        """
        What the lambda-return recursion needs of the transitions at ``(slots, envs)``, as NumPy arrays.

        Each transition t is read as the window of the buffer's ``n_steps`` (1 for a one-step buffer) steps that its
        n-step TD target spans: from t to e = t + k - 1, where k = n_steps unless the episode did not go on after an
        earlier step (it ended, was cut by a reset, or that step is the newest of an episode still running), as in
        SB3's ``NStepReplayBuffer``; the fields below ending in "at e" are those of the window's last transition.

        :param gamma: the discount of the rewards within a window
        :param lengths: each transition's own window length in steps, in place of ``n_steps`` (the horizons that
            OffOnQRDQN's ``lambda_cache=False`` draws), shortened likewise where the episode did not go on
        :return: ``rewards`` (sum over the window of gamma^i r_{t+i}, the rewards normalised as ``sample()`` normalises
            them), ``discounts`` (gamma^k), ``next_actions`` (at e; -1: the episode did not go on from e, always the
            case when k < n_steps), ``terminated`` (e ended its episode by termination, not by a time limit),
            ``running_newest`` (e is the newest transition of an episode still running), ``next_observations``
            (s_{t+k}, normalised as ``sample()`` normalises them, as :class:`sb3_offon.common.stored_rows.StoredRows`:
            read chunk by chunk, never all at once unless asked), ``lengths`` (k)
        """
        wanted = np.full(len(slots), self.n_steps) if lengths is None else np.asarray(lengths, dtype=np.int64)
        n_steps = int(wanted.max()) if len(wanted) else 1
        offsets = np.arange(n_steps)
        window = (slots[:, None] + offsets) % self.buffer_size
        # The window stops at its first step whose episode did not go on (recorded next action -1): an episode's end,
        # a reset, or the newest transition; so it never reaches past the newest transition into older data
        lengths = wanted
        if n_steps > 1:
            stops = (self.next_actions[window[:, :-1], envs[:, None]] < 0) & (offsets[:-1] < wanted[:, None] - 1)
            lengths = np.where(stops.any(axis=1), stops.argmax(axis=1) + 1, wanted)
        ends = window[np.arange(len(slots)), lengths - 1]
        window_rewards = self._normalize_reward(self.rewards[window, envs[:, None]], env)  # type: ignore[attr-defined]
        rewards = np.where(offsets < lengths[:, None], window_rewards * gamma**offsets, 0.0).sum(axis=1)
        # Where the next observations are, read chunk by chunk by whoever passes them through a network
        if self.optimize_memory_usage:
            next_obs = StoredRows(self.observations, (ends + 1) % self.buffer_size, envs, self._normalizer(env))
        else:
            next_obs = StoredRows(self.next_observations, ends, envs, self._normalizer(env))
        dones = self.dones[ends, envs]  # type: ignore[attr-defined]
        timeouts = self.timeouts[ends, envs]  # type: ignore[attr-defined]
        newest_slot = (self.pos - 1) % self.buffer_size
        running = self.episode_starts < self._n_adds
        return {
            "rewards": rewards,
            "discounts": gamma ** lengths.astype(np.float64),
            "lengths": lengths,
            "next_actions": self.next_actions[ends, envs],
            "terminated": (dones * (1 - timeouts)) > 0,
            "running_newest": (ends == newest_slot) & running[envs],
            "next_observations": next_obs,
        }

    def _normalizer(self, env: VecNormalize | None) -> Callable[[Any], Any]:
        """What ``sample()`` applies to observations: ``env``'s normalisation, or nothing."""
        return lambda observations: self._normalize_obs(observations, env)  # type: ignore[attr-defined]

    def observations_and_actions(
        self, slots: np.ndarray, envs: np.ndarray, env: VecNormalize | None = None
    ) -> tuple[np.ndarray | dict[str, np.ndarray], np.ndarray]:
        """The observations (normalised as ``sample()`` normalises them) and actions at ``(slots, envs)``, as NumPy arrays."""
        if isinstance(self.observations, dict):
            observations: Any = {key: value[slots, envs] for key, value in self.observations.items()}
        else:
            observations = self.observations[slots, envs]
        return self._normalize_obs(observations, env), self.actions[slots, envs]  # type: ignore[attr-defined]

    def _sarsa_next_actions(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """The action taken at the state that each sample's TD target bootstraps from (-1 where unknown)."""
        n_steps = self.n_steps
        if n_steps == 1:
            return self.next_actions[batch_inds, env_indices]
        # n-step: the action at s_{t+n}. It is known only if the episode went on for all n steps, i.e. every step of
        # the window has a recorded next action (an episode end or the newest step has none, which also cuts the
        # n-step return short, so the target then falls back to Q-learning).
        window = (batch_inds[:, None] + np.arange(n_steps)) % self.buffer_size
        chain = self.next_actions[window, env_indices[:, None]]
        return np.where((chain[:, :-1] >= 0).all(axis=1), chain[:, -1], UNKNOWN_ACTION)


class OffOnReplayBuffer(OffOnBufferMixin, ReplayBuffer):
    """
    SB3's ``ReplayBuffer`` that also records each transition's Monte-Carlo return and next action.

    :param buffer_size: Max number of element in the buffer
    :param observation_space: Observation space
    :param action_space: Action space (Discrete)
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Enable a memory efficient variant of the replay buffer
    :param handle_timeout_termination: Handle timeout termination (due to timelimit) separately
    :param gamma: Discount factor of the Monte-Carlo returns
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        gamma: float = 0.99,
    ):
        super().__init__(
            buffer_size, observation_space, action_space, device, n_envs, optimize_memory_usage, handle_timeout_termination
        )
        self._init_offon(gamma)


class OffOnNStepReplayBuffer(OffOnBufferMixin, NStepReplayBuffer):
    """
    SB3's ``NStepReplayBuffer`` that also records Monte-Carlo returns and next actions.
    The Sarsa target uses the action taken at the n-th next state.

    :param buffer_size: Max number of element in the buffer
    :param observation_space: Observation space
    :param action_space: Action space (Discrete)
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported
    :param handle_timeout_termination: Handle timeout termination (due to timelimit) separately
    :param n_steps: Number of steps to accumulate rewards for n-step returns
    :param gamma: Discount factor of the n-step and Monte-Carlo returns
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        n_steps: int = 3,
        gamma: float = 0.99,
    ):
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device,
            n_envs,
            optimize_memory_usage,
            handle_timeout_termination,
            n_steps=n_steps,
            gamma=gamma,
        )
        self._init_offon(gamma)


class OffOnDictReplayBuffer(OffOnBufferMixin, DictReplayBuffer):
    """
    SB3's ``DictReplayBuffer`` (Dict observations) that also records Monte-Carlo returns and next actions.

    :param buffer_size: Max number of element in the buffer
    :param observation_space: Observation space (Dict)
    :param action_space: Action space (Discrete)
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported by SB3's DictReplayBuffer
    :param handle_timeout_termination: Handle timeout termination (due to timelimit) separately
    :param gamma: Discount factor of the Monte-Carlo returns
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Dict,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        gamma: float = 0.99,
    ):
        super().__init__(
            buffer_size, observation_space, action_space, device, n_envs, optimize_memory_usage, handle_timeout_termination
        )
        self._init_offon(gamma)


def _keep_numpy(array: np.ndarray, copy: bool = True) -> np.ndarray:
    # Stands in for to_torch while a minibatch is gathered to be concatenated with others before one upload
    return array


def _to_device(value: Any, to_torch: Callable[[np.ndarray], th.Tensor]) -> Any:
    """A column of samples on the device: arrays are uploaded, dicts of them too; tensors and None stay as they are."""
    if isinstance(value, np.ndarray):
        return to_torch(value)
    if isinstance(value, dict):
        return {key: _to_device(item, to_torch) for key, item in value.items()}
    return value


def _concatenate(parts: list[Any]) -> Any:
    """Minibatches (NamedTuples of arrays, dicts of arrays or None) concatenated column by column."""
    first = parts[0]
    if isinstance(first, tuple):
        return type(first)(*(_concatenate([part[i] for part in parts]) for i in range(len(first))))
    if isinstance(first, dict):
        return {key: _concatenate([part[key] for part in parts]) for key in first}
    if first is None:
        return None
    return np.concatenate(parts)
