"""
SIGTERM ends a command-line run with a checkpoint of the step it reached, not wherever the signal lands.

SIGTERM is how a process is asked to end: ``kill``, a batch scheduler at a job's time limit or on preemption (Slurm
sends it, then SIGKILL after its ``KillWait``), ``docker stop``, systemd. Python's default is to die at once, and a run
that writes a checkpoint every 20,000 steps loses up to 20,000 steps of training. Under ``python -m sb3_offon.train``:

- in training, with ``--checkpoint-freq``: the signal is noted, the run goes on to the next rollout start (the point
  where :class:`sb3_offon.resume.RunCheckpoint` writes its checkpoints, between one rollout's gradient steps and the
  next rollout; an evaluation under way finishes first), writes a checkpoint of that step there, and stops (in the
  last rollout, where no rollout start follows: at the end of training, with a checkpoint of the budget). The zoo
  saves the model trained so far, the command says which checkpoint to go on from, and exits with status 143
  (128 + 15, the shell's status of a process ended by SIGTERM);
- elsewhere (the run's set-up, a run without checkpoints, the evaluation after training, the saving): the run stops
  where it is, as Ctrl-C stops it (a ``KeyboardInterrupt``), with the same line and status 143.

Between the signal and the stop there is the rest of a rollout, an evaluation under way and the checkpoint's writing
(seconds for a vector task; for an Atari 100k run, its 100,000-transition replay buffer): a scheduler's grace period
must cover them (Slurm: ``--signal=TERM@120`` or a longer ``KillWait``).

A run that plays games after training (``final_eval_episodes``, the Atari 100k settings) checkpoints its trained model
before them (``OffOnExperimentManager.checkpoint_trained`` in :mod:`sb3_offon.zoo`): cut during the games, it resumes at its
budget, trains no further and plays them.

Outside the command line (a ``model.learn`` in a script) nothing changes: no handler is set.
"""

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

# The exit status of a command ended by SIGTERM: the shell's for a process killed by it (128 + 15)
TERMINATED = 128 + signal.SIGTERM


class Terminated(KeyboardInterrupt):
    """
    SIGTERM's stop of a run: a ``KeyboardInterrupt``, so that what handles Ctrl-C (the zoo's saving of the model trained
    so far, the command line's last line) handles it, and what does not know it treats it as the interruption it is.
    """

    def __init__(self, message: str = "stopped by SIGTERM") -> None:
        super().__init__(message)


@dataclass
class TerminationRequest:
    """
    The state of SIGTERM in this process: whether it has been received, whether it has been handled, and whether a run
    in training takes it at its next rollout start (``deferred``) instead of where it lands.
    """

    installed: bool = False
    received: bool = False
    deferred: bool = False

    def handle(self, signum: int, frame: Any) -> None:
        """The signal handler: note the request; outside a deferring run, stop where the signal lands."""
        self.received = True
        if not self.deferred:
            raise Terminated

    @property
    def pending(self) -> bool:
        """Whether a run that deferred the signal must stop now (the signal came and is this process's to take)."""
        return self.installed and self.received


TERMINATION = TerminationRequest()


@contextmanager
def sigterm_stops_the_run() -> Iterator[None]:
    """
    Inside the block, SIGTERM stops the run as the module's docstring says; the previous handler is back after it. Where
    no handler can be set (outside the main thread) the block runs as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, TERMINATION.handle)
    TERMINATION.installed, TERMINATION.received, TERMINATION.deferred = True, False, False
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        TERMINATION.installed, TERMINATION.deferred = False, False


@contextmanager
def termination_deferred() -> Iterator[None]:
    """
    Inside the block (a run's training with a :class:`sb3_offon.resume.RunCheckpoint`), SIGTERM is only noted: the
    checkpoint callback writes a checkpoint at the next rollout start and raises :class:`Terminated` there. A signal
    that came before the block is taken at once.
    """
    if TERMINATION.pending:
        raise Terminated
    previous = TERMINATION.deferred
    TERMINATION.deferred = True
    try:
        yield
    finally:
        TERMINATION.deferred = previous
