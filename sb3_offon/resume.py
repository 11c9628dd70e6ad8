"""
Checkpoints from which an interrupted training run goes on where it stopped.

SB3 saves a model and its replay buffer, and ``learn(..., reset_num_timesteps=False)`` continues its step count, but
what a *run* is also lives outside the model: the evaluations so far (SB3's ``EvalCallback`` keeps them in memory and
rewrites ``evaluations.npz`` from them), the training episodes in the ``Monitor`` files, the evaluation schedule (the
callback's own call count), the running state of other callbacks (a stop rule's window of recent episodes), and the
budget the schedules were made for. rl-baselines3-zoo's ``-i`` (continue training) starts a new run from a model: the
step count, ε and the evaluation steps start again from 0. A checkpoint here holds all of it, so that a resumed run has
the evaluation steps, ε schedule, learning start, target updates, stop rule and budget of an uninterrupted one.

What differs from an uninterrupted run, by design:

- the episode running at the checkpoint is cut: its last stored transition is marked as a time-limit truncation
  (bootstrapped, as a time limit is; OffOnDQN's buffers also close its returns that way), the env is reset, and the
  ``Monitor`` files lack that one unfinished episode;
- the random generators (Python, NumPy, torch, action space, training and evaluation envs) are seeded afresh from the
  run's seed and the checkpoint's step (:func:`resumed_seed`), not restored: a resumed run is reproducible from its seed
  and the steps it resumed at, but not bit-identical to the uninterrupted run;
- with ``optimize_memory_usage`` (next observations not stored) the cut transition's next observation becomes the
  reset observation: use checkpoints without that option where this matters.

Layout: a sub-folder ``<folder>/<num_timesteps>/`` per checkpoint holding ``model.zip``, ``replay_buffer.pkl``,
``evaluations.npz``, the joined monitor files, the ``VecNormalize`` statistics when the env is normalised
(``vecnormalize.pkl``; ``<env name>/vecnormalize.pkl`` from the command line, where the zoo looks for them), and, written
last, ``checkpoint.json``: the run's state, the size of every file (so that a truncated file is told from a complete
one), the algorithm's class, and what the command line ran (its ``--algo`` and hyperparameters, which ``--resume``
compares with its own). ``<folder>/latest`` names the newest. The two newest complete checkpoints are kept: a run resumes
from the newest complete one, and from the one before it, with a warning naming what is wrong, when the newest is
damaged (a run killed while writing it, a file lost or truncated). A checkpoint is written in full and synced before
``latest`` is replaced (atomically) and older ones are removed.
"""

import json
import os
import shutil
import signal
import threading
import warnings
import zipfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, EvalCallback

from sb3_offon.termination import TERMINATION, Terminated

LATEST = "latest"
# The complete checkpoints a run keeps: the newest, and one to fall back to if the newest turns out damaged
KEPT_CHECKPOINTS = 2
STATE_FILE = "checkpoint.json"
MODEL_FILE = "model.zip"
# The zoo's _load_pretrained_agent loads a replay buffer of this name next to the model
REPLAY_BUFFER_FILE = "replay_buffer.pkl"
EVALUATIONS_FILE = "evaluations.npz"
MONITOR_SUFFIX = "monitor.csv"
# Written into a run's log folder by the command line when a callback of its own ended it before its budget on purpose
STOPPED_FILE = "stopped.json"


class CheckpointError(ValueError):
    """A checkpoint that cannot be resumed: none complete, or made by another algorithm or with other settings."""


def checkpoint_problem(folder: Path) -> str | None:
    """
    What makes the checkpoint in ``folder`` unusable, in a few words (None when it is complete): ``checkpoint.json``
    missing or unreadable (written last, its absence means the writing was cut off), a file it lists missing or of
    another size than written, ``model.zip`` not a readable zip.
    """
    state_file = folder / STATE_FILE
    if not state_file.is_file():
        return f"no {STATE_FILE} (its writing was cut off)"
    try:
        state = json.loads(state_file.read_text())
    except (OSError, ValueError) as error:
        return f"{STATE_FILE} unreadable ({error})"
    # Checkpoints from before the sizes were recorded: the files they must have, not empty
    sizes = state.get("file_sizes") or {
        name: None for name in [MODEL_FILE, *([REPLAY_BUFFER_FILE] if state.get("replay_buffer") else [])]
    }
    for name, size in sizes.items():
        path = folder / name
        if not path.is_file():
            return f"{name} missing"
        actual = path.stat().st_size
        if (size is None and actual == 0) or (size is not None and actual != size):
            return f"{name} truncated ({actual} of {size if size is not None else 'more than 0'} bytes)"
    if not zipfile.is_zipfile(folder / MODEL_FILE):
        return f"{MODEL_FILE} not a readable zip"
    return None


def checkpoint_folders(folder: str | Path) -> list[Path]:
    """The checkpoint sub-folders under ``folder`` (named by their step), the newest first."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted((path for path in folder.iterdir() if path.is_dir() and path.name.isdigit()), key=lambda p: -int(p.name))


@contextmanager
def n_step_reload_unflagged() -> Iterator[None]:
    """
    Loading a model inside this block, SB3's warning that its ``n_steps`` is ignored is not shown: a model that SB3 gave
    an n-step buffer (``n_steps`` > 1 and no buffer class) was saved with that class and its n in
    ``replay_buffer_kwargs``, which build the same buffer again (and a checkpoint's buffer replaces it), so nothing is
    ignored; SB3 warns because the class is now given.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored because a custom `replay_buffer_class`")
        yield


@contextmanager
def interrupts_held() -> Iterator[None]:
    """
    A Ctrl-C (SIGINT) that arrives inside the block takes effect when the block ends, not inside it. A KeyboardInterrupt
    raised inside torch's zip writer leaves the writer in a state whose cleanup raises a RuntimeError, which replaces the
    KeyboardInterrupt: the run would end in a traceback, not in the interruption line. A checkpoint takes a moment to
    write, so the interrupt waits for it. So does a SIGTERM whose handler is Python's (the command line's,
    :mod:`sb3_offon.termination`); under the default one (the process dies) nothing is held. Outside the main thread
    (where no signal handler can be set), or where SIGINT's handler was not set from Python (``signal.getsignal`` gives
    None, which cannot be put back), the block runs as it is.
    """
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is None:
        yield
        return
    held = [signal.SIGINT, *([signal.SIGTERM] if callable(signal.getsignal(signal.SIGTERM)) else [])]
    received: list[tuple[int, Any]] = []
    previous = {signum: signal.signal(signum, lambda signum, frame: received.append((signum, frame))) for signum in held}
    try:
        yield
    finally:
        for held_signal, handler in previous.items():
            signal.signal(held_signal, handler)
    # Taken in the order they came; the first that raises ends the block's caller
    for number, frame in received:
        handler = previous[signal.Signals(number)]
        if callable(handler):
            handler(number, frame)
        elif handler == signal.SIG_DFL:
            signal.raise_signal(number)


def resumed_seed(seed: int | None, num_timesteps: int) -> int:
    """
    The seed of a run's random generators from a resume on: a function of the run's seed and the step it resumed at,
    drawn through NumPy's ``SeedSequence`` so that it does not coincide with the plain seed of another run.

    :param seed: the run's seed (None: 0)
    :param num_timesteps: the checkpoint's step
    :return: a seed in [0, 2**31)
    """
    return int(np.random.SeedSequence([seed or 0, num_timesteps]).generate_state(1)[0] >> 1)


def joined_monitor(earlier: str | None, current: str) -> str:
    """
    The text of one ``Monitor`` file that covers a run across a resume: the earlier part's header and episodes, then
    the current part's episodes, their times (``t``, seconds since the monitor started) shifted to the earlier start.

    :param earlier: the earlier part's text (None: the run was not resumed, ``current`` is returned)
    :param current: the text the current part's ``Monitor`` wrote
    :return: the joined text
    """
    if not earlier:
        return current
    earlier_lines = earlier.splitlines()
    current_lines = current.splitlines()
    if len(current_lines) < 2:
        return earlier
    shift = json.loads(current_lines[0][1:])["t_start"] - json.loads(earlier_lines[0][1:])["t_start"]
    t_column = current_lines[1].split(",").index("t")
    rows = []
    for line in current_lines[2:]:
        cells = line.split(",")
        cells[t_column] = str(round(float(cells[t_column]) + shift, 6))
        rows.append(",".join(cells))
    return "\n".join([*earlier_lines, *rows]) + "\n"


def save_evaluations(callback: EvalCallback, path: str | Path) -> None:
    """Write an ``EvalCallback``'s evaluations so far as it writes its ``evaluations.npz``."""
    arrays: dict[str, Any] = {
        "timesteps": callback.evaluations_timesteps,
        "results": callback.evaluations_results,
        "ep_lengths": callback.evaluations_length,
    }
    if callback.evaluations_successes:
        arrays["successes"] = callback.evaluations_successes
    np.savez(path, **arrays)


def synced(folder: Path) -> None:
    """Flush every file under ``folder``, and the folder entries, to the disk (``fsync``)."""
    # Files before the folders that list them, the folder itself last
    for path in [*sorted(folder.rglob("*"), reverse=True), folder]:
        descriptor = os.open(path, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


def stateful_callbacks(callbacks: Sequence[BaseCallback]) -> list[BaseCallback]:
    """
    The callbacks among ``callbacks`` (and inside any ``CallbackList``) whose running state a checkpoint keeps: those
    with ``get_state()`` (a JSON-serialisable dict) and ``set_state(state)``, as :mod:`sb3_offon.callbacks`' have.
    """
    found: list[BaseCallback] = []
    for callback in callbacks:
        if isinstance(callback, CallbackList):
            found.extend(stateful_callbacks(callback.callbacks))
        elif callable(getattr(callback, "get_state", None)) and callable(getattr(callback, "set_state", None)):
            found.append(callback)
    return found


def cut_running_episodes(replay_buffer: ReplayBuffer) -> None:
    """
    Mark each env's last stored transition, unless it ended its episode, as a time-limit truncation (done and
    timeout), as SB3's buffers store one: the env is reset after it, so the next transition belongs to a new episode.

    Without ``handle_timeout_termination`` a timeout cannot be told from a terminal state, and the transition is left
    as it is (a one-step target still bootstraps from its stored next observation).

    :param replay_buffer: the buffer, as loaded from a checkpoint
    """
    if not replay_buffer.handle_timeout_termination or (replay_buffer.pos == 0 and not replay_buffer.full):
        return
    last = (replay_buffer.pos - 1) % replay_buffer.buffer_size
    running = replay_buffer.dones[last] == 0
    replay_buffer.timeouts[last] = np.logical_or(replay_buffer.timeouts[last], running)
    replay_buffer.dones[last] = np.logical_or(replay_buffer.dones[last], running)


@dataclass
class Checkpoint:
    """
    A complete checkpoint on disk (see the module's docstring for its files).

    :param folder: its folder, ``<checkpoint folder>/<num_timesteps>``
    :param num_timesteps: the run's step count when it was written
    :param total_timesteps: the run's budget (the schedules' horizon)
    :param seed: the run's seed
    :param resumed_at: the steps at which the run was resumed before this checkpoint was written
    :param best_mean_reward: the evaluation callback's best mean return so far
    :param last_mean_reward: its latest mean return
    :param saved: when it was written (UTC, ISO 8601)
    :param replay_buffer: whether the checkpoint holds the model's replay buffer (None: not recorded, older checkpoints)
    :param callback_states: the running state of the run's callbacks that have one (:func:`stateful_callbacks`), as
        ``[class name, state]`` in the callbacks' order
    :param monitor_texts: the run's monitor files up to this checkpoint, by file name (read with the checkpoint: a
        resumed run writing its own checkpoints into the same folder removes this one)
    :param algorithm: the model's class name (None: not recorded, older checkpoints)
    :param run_config: what made the run, as the command line records it (``algo``, ``env``, ``hyperparams``; empty:
        not recorded)
    :param file_sizes: the size in bytes of each file of the checkpoint when it was written
    """

    folder: Path
    num_timesteps: int
    total_timesteps: int
    seed: int | None
    resumed_at: list[int] = field(default_factory=list)
    best_mean_reward: float = -np.inf
    last_mean_reward: float = -np.inf
    saved: str = ""
    replay_buffer: bool | None = None
    callback_states: list[list[Any]] = field(default_factory=list)
    monitor_texts: dict[str, str] = field(default_factory=dict)
    algorithm: str | None = None
    run_config: dict[str, Any] = field(default_factory=dict)
    file_sizes: dict[str, int] = field(default_factory=dict)

    @classmethod
    def latest(cls, folder: str | Path) -> "Checkpoint | None":
        """
        The newest complete checkpoint under ``folder`` (None when there is none); when newer ones are damaged
        (:func:`checkpoint_problem`), a warning says what is wrong with each.

        :param folder: the checkpoint folder of a run (``--checkpoint-dir``)
        :raises CheckpointError: when there are checkpoints but none is complete, saying what each lacks
        """
        candidates = checkpoint_folders(folder)
        problems: list[str] = []
        for candidate in candidates:
            problem = checkpoint_problem(candidate)
            if problem is None:
                if problems:
                    warnings.warn(
                        f"Checkpoints in {folder}: {'; '.join(problems)}: resuming from the one of step {candidate.name}",
                        stacklevel=2,
                    )
                return cls.read(candidate)
            problems.append(f"step {candidate.name}: {problem}")
        if problems:
            raise CheckpointError(f"No complete checkpoint in {folder}: {'; '.join(problems)}")
        return None

    @classmethod
    def read(cls, folder: Path) -> "Checkpoint":
        """The checkpoint in ``folder`` (complete: see :func:`checkpoint_problem`)."""
        state = json.loads((folder / STATE_FILE).read_text())
        monitors = {path.name: path.read_text() for path in sorted(folder.glob(f"*{MONITOR_SUFFIX}"))}
        return cls(folder=folder, monitor_texts=monitors, **state)

    def check_algorithm(self, algo_class: type[BaseAlgorithm]) -> None:
        """:raises CheckpointError: if the checkpoint records a model of another class than ``algo_class``."""
        if self.algorithm is not None and self.algorithm != algo_class.__name__:
            raise CheckpointError(
                f"The checkpoint in {self.folder} holds a {self.algorithm} model, not a {algo_class.__name__}: resume it "
                "with the algorithm it was made by"
            )

    @property
    def model_path(self) -> Path:
        return self.folder / MODEL_FILE

    def restore_evaluations(self, callback: EvalCallback, n_envs: int) -> None:
        """
        Give an evaluation callback the evaluations made before this checkpoint and the call count of the run's step,
        so that it evaluates at the uninterrupted run's steps and writes every evaluation into its file.

        :param callback: the resumed run's ``EvalCallback`` (before training starts)
        :param n_envs: the run's number of training envs
        """
        path = self.folder / EVALUATIONS_FILE
        if path.is_file():
            with np.load(path) as data:
                callback.evaluations_timesteps = [int(step) for step in data["timesteps"]]
                callback.evaluations_results = [list(row) for row in data["results"]]
                callback.evaluations_length = [list(row) for row in data["ep_lengths"]]
                if "successes" in data:
                    callback.evaluations_successes = [list(row) for row in data["successes"]]
        callback.best_mean_reward = self.best_mean_reward
        callback.last_mean_reward = self.last_mean_reward
        # EvalCallback evaluates when its call count (one call per vectorised step) is a multiple of eval_freq
        callback.n_calls = self.num_timesteps // n_envs
        if callback.log_path is not None and callback.evaluations_timesteps:
            # EvalCallback writes its file only when it evaluates: a run resumed after its last evaluation (a budget
            # that is not a multiple of eval_freq) would otherwise end with no file, its evaluations only in here
            os.makedirs(os.path.dirname(callback.log_path) or ".", exist_ok=True)
            save_evaluations(callback, callback.log_path)

    def restore_callbacks(self, callbacks: Sequence[BaseCallback]) -> None:
        """
        Give the resumed run's callbacks that have a running state (:func:`stateful_callbacks`) the state they had at
        this checkpoint: a stop rule's window of recent episodes, a running count.

        :param callbacks: the resumed run's callbacks, as the interrupted run had them
        """
        current = stateful_callbacks(callbacks)
        names = [type(callback).__name__ for callback in current]
        if names != [name for name, _ in self.callback_states]:
            raise ValueError(
                f"The checkpoint in {self.folder} holds the state of the callbacks {[n for n, _ in self.callback_states]}, "
                f"the resumed run has {names}: resume a run with the callbacks it was started with"
            )
        for callback, (_, state) in zip(current, self.callback_states, strict=True):
            callback.set_state(state)  # type: ignore[attr-defined]

    def prepare(
        self, model: BaseAlgorithm, eval_callback: EvalCallback | None = None, callbacks: Sequence[BaseCallback] = ()
    ) -> None:
        """
        Make a model loaded from this checkpoint (with its replay buffer) go on as the interrupted run: the last stored
        transitions cut as truncations (:func:`cut_running_episodes`), the random generators seeded for the resumed part
        (:func:`resumed_seed`), the evaluation callback holding the evaluations so far, and the other callbacks their
        running state (:meth:`restore_callbacks`).

        :param model: the model, loaded with its replay buffer
        :param eval_callback: the resumed run's evaluation callback (None: none)
        :param callbacks: the resumed run's callbacks (those with a running state get it back)
        """
        if getattr(model, "replay_buffer", None) is not None:
            cut_running_episodes(model.replay_buffer)  # type: ignore[attr-defined]
        seed = resumed_seed(self.seed, self.num_timesteps)
        model.set_random_seed(seed)
        if eval_callback is not None:
            self.restore_evaluations(eval_callback, model.n_envs)
            eval_callback.eval_env.seed(seed + 1)
        self.restore_callbacks(callbacks)

    def load_model(
        self,
        algo_class: type[BaseAlgorithm],
        env: Any,
        eval_callback: EvalCallback | None = None,
        callbacks: Sequence[BaseCallback] = (),
        **kwargs: Any,
    ) -> BaseAlgorithm:
        """
        The interrupted run's model, ready to go on (the Python way; the command line's is ``--resume``)::

            checkpoint = Checkpoint.latest("checkpoints")
            model = checkpoint.load_model(OffOnDQN, env, eval_callback)
            model.learn(checkpoint.total_timesteps - model.num_timesteps, reset_num_timesteps=False,
                        callback=[eval_callback, RunCheckpoint("checkpoints", 10_000, eval_callback, resumed_from=checkpoint)])

        The training monitor files of the part before the checkpoint are in ``monitor_texts``
        (:func:`joined_monitor` joins one to the resumed part's file).

        :param algo_class: the model's class
        :param env: the training env, made as the interrupted run's was (and, if that run normalised it, wrapped in
            ``VecNormalize.load`` of the checkpoint's ``vecnormalize.pkl``)
        :param eval_callback: the resumed run's evaluation callback (None: none)
        :param callbacks: the resumed run's other callbacks (those with a running state get it back)
        :param kwargs: more arguments of ``algo_class.load`` (``device``, ``custom_objects``, ...)
        :return: the model, its replay buffer loaded
        """
        self.check_algorithm(algo_class)
        with n_step_reload_unflagged():
            model = algo_class.load(self.model_path, env=env, **kwargs)
        buffer = self.folder / REPLAY_BUFFER_FILE
        if buffer.is_file():
            # truncate_last_traj: OffOnDQN's buffers close their running episodes' returns as truncations
            model.load_replay_buffer(buffer, truncate_last_traj=True)  # type: ignore[attr-defined]
        self.prepare(model, eval_callback, callbacks)
        return model


class RunCheckpoint(BaseCallback):
    """
    Every ``every`` env steps, write a checkpoint of the run into ``folder`` (see the module's docstring); a run started
    with :meth:`Checkpoint.latest` of that folder then goes on from the newest.

    A checkpoint is written at the first rollout start (SB3's off-policy loop collects ``train_freq`` steps, then trains)
    at or after each multiple of ``every``: with DQN's ``train_freq`` of 4 and ``every`` a multiple of 4, at the
    multiple itself, after the evaluation of that step.

    :param folder: where the checkpoints go (created if needed); older checkpoints there are removed
    :param every: env steps between checkpoints (counted over all envs, as ``num_timesteps``)
    :param eval_callback: the run's evaluation callback, whose evaluations the checkpoint keeps (None: none; SB3's
        ``EvalCallback`` records its evaluations only when it has a ``log_path``)
    :param monitor_dir: the folder of the run's ``Monitor`` files (None: none kept)
    :param resumed_from: the checkpoint this run was resumed from (its monitor files are the start of this run's)
    :param vec_normalize_path: where in a checkpoint the ``VecNormalize`` statistics go, if the env has them
        (rl-baselines3-zoo loads them from ``<env name>/vecnormalize.pkl`` next to the model it continues)
    :param callbacks: the run's other callbacks: the running state of those that have one (:func:`stateful_callbacks`)
        is kept in each checkpoint
    :param run_config: what made the run, kept in each checkpoint for a resume to compare with (the command line's
        ``algo``, ``env`` and ``hyperparams``; JSON-serialisable)
    :param verbose: 1: a line per checkpoint written
    """

    def __init__(
        self,
        folder: str | Path,
        every: int,
        eval_callback: EvalCallback | None = None,
        monitor_dir: str | Path | None = None,
        resumed_from: Checkpoint | None = None,
        vec_normalize_path: str = "vecnormalize.pkl",
        callbacks: Sequence[BaseCallback] = (),
        run_config: dict[str, Any] | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if every <= 0:
            raise ValueError(f"`every` must be a positive number of env steps, got {every}")
        self.folder = Path(folder)
        self.every = every
        self.eval_callback = eval_callback
        self.monitor_dir = Path(monitor_dir) if monitor_dir is not None else None
        self.resumed_from = resumed_from
        self.vec_normalize_path = vec_normalize_path
        self.stateful = stateful_callbacks(callbacks)
        self.run_config = dict(run_config or {})
        self._next_step = 0
        # The step of the newest checkpoint this run has (the one it resumed from, until it writes one)
        self._saved_step = resumed_from.num_timesteps if resumed_from is not None else None
        self._stopped = False

    def _on_training_start(self) -> None:
        self._next_step = (self.model.num_timesteps // self.every + 1) * self.every

    def _on_rollout_start(self) -> None:
        # Between rollouts, where the previous rollout's gradient steps are done and the next has not begun: a run
        # resumed from here collects and trains on the uninterrupted run's steps (train_freq counts within a rollout)
        if self.model.num_timesteps >= self._next_step:
            self.save()
            self._next_step = (self.model.num_timesteps // self.every + 1) * self.every
        self._stop_if_terminated()

    def _on_training_end(self) -> None:
        # A SIGTERM in the last rollout: no rollout start follows, the stop comes here
        self._stop_if_terminated()

    def _stop_if_terminated(self) -> None:
        """Under SIGTERM (the command line's, :mod:`sb3_offon.termination`): this step's checkpoint, then the stop."""
        # Once: the zoo calls its first callback's on_training_end again after the stop
        if TERMINATION.pending and not self._stopped:
            self._stopped = True
            if self._saved_step != self.model.num_timesteps:
                self.save()
            raise Terminated(f"stopped by SIGTERM at step {self.model.num_timesteps}")

    def _on_step(self) -> bool:
        return True

    @property
    def saved_step(self) -> int | None:
        """The step of the newest checkpoint this run has: the one it wrote last, or the one it resumed from (None: none)."""
        return self._saved_step

    def joined_monitor_texts(self) -> dict[str, str]:
        """The run's monitor files from its start, by file name (the resumed-from part first)."""
        earlier = self.resumed_from.monitor_texts if self.resumed_from is not None else {}
        current = {} if self.monitor_dir is None else {path.name: path.read_text() for path in self.monitor_files()}
        return {name: joined_monitor(earlier.get(name), current.get(name, "")) for name in sorted({*earlier, *current})}

    def monitor_files(self) -> list[Path]:
        return [] if self.monitor_dir is None else sorted(self.monitor_dir.glob(f"*{MONITOR_SUFFIX}"))

    def save(self) -> Checkpoint:
        """
        Write a checkpoint of the run now, then point ``latest`` at it and remove all but the newest complete ones. A
        Ctrl-C while it writes takes effect once it is written (:func:`interrupts_held`).
        """
        with interrupts_held():
            return self._write()

    def _write(self) -> Checkpoint:
        model: BaseAlgorithm = self.model
        target = self.folder / str(model.num_timesteps)
        shutil.rmtree(target, ignore_errors=True)  # a partial one left by a killed run
        target.mkdir(parents=True)
        model.save(target / MODEL_FILE)
        if getattr(model, "replay_buffer", None) is not None:
            model.save_replay_buffer(target / REPLAY_BUFFER_FILE)  # type: ignore[attr-defined]
        vec_normalize = model.get_vec_normalize_env()
        if vec_normalize is not None:
            (target / self.vec_normalize_path).parent.mkdir(parents=True, exist_ok=True)
            vec_normalize.save(str(target / self.vec_normalize_path))
        monitors = self.joined_monitor_texts()
        for name, text in monitors.items():
            (target / name).write_text(text)
        state: dict[str, Any] = {
            "num_timesteps": model.num_timesteps,
            "total_timesteps": model._total_timesteps,
            "seed": model.seed,
            "resumed_at": [*self.resumed_from.resumed_at, self.resumed_from.num_timesteps] if self.resumed_from else [],
            "saved": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "replay_buffer": (target / REPLAY_BUFFER_FILE).is_file(),
            "callback_states": [[type(callback).__name__, callback.get_state()] for callback in self.stateful],  # type: ignore[attr-defined]
        }
        if self.eval_callback is not None:
            callback = self.eval_callback
            if callback.evaluations_timesteps:
                save_evaluations(callback, target / EVALUATIONS_FILE)
            state.update(best_mean_reward=float(callback.best_mean_reward), last_mean_reward=float(callback.last_mean_reward))
        state.update(algorithm=type(model).__name__, run_config=self.run_config)
        # Every file but this state, which is written last: its presence says the others are complete
        state["file_sizes"] = {
            str(path.relative_to(target)): path.stat().st_size for path in sorted(target.rglob("*")) if path.is_file()
        }
        (target / STATE_FILE).write_text(json.dumps(state, indent=2))
        # On disk before `latest` names it, so that a power cut cannot leave `latest` naming a checkpoint with empty files
        synced(target)
        pointer = self.folder / f"{LATEST}.tmp"
        pointer.write_text(target.name)
        os.replace(pointer, self.folder / LATEST)
        # Kept: this one and the newest complete ones before it; removed: older ones and any a killed run left partial
        complete = [folder for folder in checkpoint_folders(self.folder) if checkpoint_problem(folder) is None]
        kept = {target, *complete[:KEPT_CHECKPOINTS]}
        for older in self.folder.iterdir():
            if older.is_dir() and older not in kept:
                shutil.rmtree(older, ignore_errors=True)
        self._saved_step = model.num_timesteps
        if self.verbose >= 1:
            print(f"Checkpoint of step {model.num_timesteps} written to {target}")
        return Checkpoint(folder=target, monitor_texts=monitors, **state)
