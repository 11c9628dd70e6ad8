"""
``python -m sb3_offon.train``: rl-baselines3-zoo's ``train`` with the sb3_offon algorithms registered.

Every flag of ``python -m rl_zoo3.train`` works (``--algo``, ``--env``, ``-n``, ``--seed``, ``-f``, ``--eval-freq``,
``--eval-episodes``, ``--save-freq``, ``--tensorboard-log``, ``--progress``, ``--hyperparams``, ``-optimize`` with
``--storage``/``--study-name``, ...). Without ``-conf`` the hyperparameters come from ``sb3_offon/hyperparams``;
``-conf paper`` selects the paper's settings (see :mod:`sb3_offon.zoo`). String values need no quotes:
``--hyperparams mc_mixing:convex sarsa_target:expected`` (see :mod:`sb3_offon.cli_args`).

Additions to the zoo's command line: ``--help`` opens with the algorithms this package adds (read from
:data:`sb3_offon.zoo.ALGOS`) and where their settings are documented; an invalid value of one of OffOnDQN's own
arguments (``--hyperparams mc_mixing:foo``) ends with one line naming the argument and its allowed values, on stderr
with exit status 2 as argparse's errors, instead of a traceback, and so do an unknown ``--algo`` or env id or
hyperparameter (with the close matches), an env whose action space the algorithm cannot take (a continuous one for
the DQN family) and a ``--resume`` refused (another algorithm, env, hyperparameters or budget; no complete checkpoint);
a run on a bundled file's ``default`` entry (no settings for its env) is warned about in one line; a non-finite reward
or loss ends the run with one line and exit status 1 (:mod:`sb3_offon.common.non_finite`); Ctrl-C ends it with one
line, the newest checkpoint and the command that goes on from it, and exit status 130 (:func:`interruption_line`);
SIGTERM (``kill``, a batch scheduler) stops training at the next rollout start with a checkpoint of that step, then ends
as Ctrl-C does with status 143 (:mod:`sb3_offon.termination`);
checkpoints to resume a run from (``--checkpoint-freq``, ``--resume``); one torch thread unless ``--num-threads`` says
otherwise; and denormal floats flushed to zero on the CPU
unless ``--keep-denormals`` (see :func:`flush_denormals_unless_kept`).

Example::

    python -m sb3_offon.train --algo offon_dqn --env CartPole-v1 --seed 0 -f logs --progress \\
        --eval-freq 10000 --eval-episodes 10 --save-freq 10000
"""

import argparse
import difflib
import re
import shlex
import sys
import traceback
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType, SimpleNamespace

from sb3_offon.extras import zoo_required

PACKAGE_DIR = Path(__file__).resolve().parent
# The torch threads of a run when the command line does not say: one (see one_thread_by_default)
DEFAULT_NUM_THREADS = 1
# OffOnDQN's checks of its own arguments word their errors as "`name` must be ...": the argument's name in backticks
ARGUMENT_ERROR = re.compile(r"^`(?P<name>\w+)` must be ")
# rl_zoo3.train's error for an env id that is not registered
UNKNOWN_ENV = re.compile(r"^(?P<env>\S+) not found in gym registry")
# The exit status of a command stopped by Ctrl-C: the shell's for a process ended by SIGINT (128 + 2)
INTERRUPTED = 130


def prog(command: str = "train") -> str:
    """
    The command's name as it was run: the console script's, else ``python -m sb3_offon.<command>``.

    :param command: ``train`` or ``enjoy``
    """
    script = Path(sys.argv[0]).name if sys.argv else ""
    return script if script.startswith(f"sb3-offon-{command}") else f"python -m sb3_offon.{command}"


def help_description(algos: dict[str, type], summaries: dict[str, str] | None = None) -> str:
    """
    The paragraph that opens ``--help``: the ``--algo`` names this package adds, what each trains, and where they are
    documented.

    :param algos: the names this package registers and their classes (:data:`sb3_offon.zoo.ALGOS`)
    :param summaries: a line on what each name trains (:data:`sb3_offon.zoo.ALGO_SUMMARIES`)
    :return: the text, lines of at most 100 characters
    """
    width = max(len(name) for name in algos) + 2
    rows = []
    for name, algo in algos.items():
        summary = (summaries or {}).get(name)
        rows.append(f"  {name:<{width}}{algo.__module__.partition('.')[0]}.{algo.__name__}")
        if summary:
            rows.append(f"  {'':<{width}}  {summary}")
    return "\n".join(
        [
            "rl-baselines3-zoo's train command, with the algorithms of sb3-offon added to its --algo choices:",
            *rows,
            "The zoo's own algorithms (dqn, qrdqn, ppo, ...) work as with python -m rl_zoo3.train.",
            "",
            "Settings: without -conf, each added algorithm reads sb3_offon/hyperparams/{algo}.yml (also dqn and",
            "qrdqn, with the zoo's tuned entries); -conf paper reads the paper's, sb3_offon/hyperparams/paper/.",
            f"Installed at {PACKAGE_DIR / 'hyperparams'}.",
            "Off-On parameters (mc_initial_prob, mc_mixing, sarsa_target, ...; set them with --hyperparams",
            "name:value): the algorithm page of the docs, docs/offon_dqn.md in the source, or",
            "python -c 'import sb3_offon; help(sb3_offon.OffOnDQN)'. Command line and files: docs/cli.md.",
            f"Threads: {DEFAULT_NUM_THREADS} torch thread unless --num-threads says otherwise (-1: torch's default, one",
            "per core). DQN's small networks train fastest on one thread, several times slower with threads that",
            "compete with other processes for the cores: docs/speed.md.",
        ]
    )


def one_thread_by_default(argv: list[str]) -> list[str]:
    """
    ``argv`` with ``--num-threads 1`` added when it has no ``--num-threads`` of its own.

    The zoo leaves torch at its default, one intra-op thread per core. For the small networks of DQN that is slower than
    one thread, and far slower when other processes use the cores (the threads wait for each other): measured in
    docs/speed.md. ``--num-threads -1`` keeps the zoo's behaviour.

    :param argv: the command line's arguments (without the program name)
    :return: the arguments to run with
    """
    if any(argument == "--num-threads" or argument.startswith("--num-threads=") for argument in argv):
        return list(argv)
    return [*argv, "--num-threads", str(DEFAULT_NUM_THREADS)]


def flush_denormals_unless_kept(argv: list[str]) -> bool:
    """
    Flush denormal floats to zero on the CPU (``torch.set_flush_denormal(True)``: the FTZ and DAZ modes of x86 CPUs),
    unless ``argv`` has ``--keep-denormals``.

    Why: an optimizer state that decays geometrically (RMSprop's and Adam's running averages, for weights whose
    gradients stay zero, such as those of dead ReLU units) passes through the denormal range below 1.2e-38, where each
    arithmetic operation on x86 costs tens of times a normal one. Late in a MinAtar run a quarter of QR-DQN's centred
    RMSprop state was denormal and its gradient steps took twice as long as with them flushed (``scripts/bench_denormals.py``,
    docs/speed.md). What flushing changes: values below 1.2e-38 become 0. A weight's running averages are that small
    only after its gradients have stayed at or near zero (below about 1e-19) for hundreds of steps, and then its update,
    the learning rate times the gradient over the square root of the average plus ``eps``, is zero or far below what
    float32 can add to the weight, flushed or not: in the measurements and in tests/test_denormals.py the parameters
    came out bit-identical, only the optimizer state's denormal entries differed. The mode belongs to the calling
    thread, the one that trains (threads it starts later inherit it); the GPU's arithmetic is not affected.

    :param argv: the command line's arguments (without the program name)
    :return: whether denormals are flushed (False with ``--keep-denormals``, or on a CPU without the modes)
    """
    if "--keep-denormals" in argv:
        return False
    import torch

    return bool(torch.set_flush_denormal(True))


def add_package_arguments(parser: argparse.ArgumentParser) -> None:
    """
    The options this package adds to the zoo's: checkpoints from which an interrupted run goes on (:mod:`sb3_offon.resume`;
    the zoo's ``--save-freq`` saves models, and its ``-i`` starts a new run from one), and ``--keep-denormals``
    (:func:`flush_denormals_unless_kept`).

    :param parser: the zoo's parser
    """
    parser.add_argument(
        "--checkpoint-freq",
        type=int,
        default=0,
        help="write a checkpoint to resume the run from every n env steps (model, replay buffer, evaluations, monitor "
        "files; the two newest kept, removed when the run reaches its budget). A multiple of --eval-freq is cheapest",
    )
    parser.add_argument(
        "--checkpoint-dir",
        default=None,
        help="where the checkpoints go (default: the --resume folder, else a checkpoint/ folder in the run's log folder)",
    )
    parser.add_argument(
        "--resume",
        default=None,
        metavar="CHECKPOINT_DIR",
        help="go on with the run checkpointed in this folder (or in the checkpoint/ folder of this run folder), to its "
        "budget (-n must be the run's): its step count, schedules, evaluations and monitor files go on, in a new run "
        "folder; the random generators are seeded afresh from --seed and the step",
    )
    parser.add_argument(
        "--keep-denormals",
        action="store_true",
        help="compute with denormal floats (below 1.2e-38) on the CPU as IEEE 754 says; by default they are flushed to "
        "zero, which makes long runs up to twice as fast (optimizer states that decay into that range) and left the "
        "parameters bit-identical where measured: docs/speed.md",
    )


class DescribedArgumentParser(argparse.ArgumentParser):
    """
    An ``argparse.ArgumentParser`` whose help opens with :func:`help_description` (before the long usage line), with the
    options of :func:`add_package_arguments`, and whose error for an unknown ``--algo`` is one line.
    """

    description_text = ""

    def __init__(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        kwargs.setdefault("prog", prog())
        super().__init__(*args, **kwargs)
        add_package_arguments(self)

    def format_help(self) -> str:
        """The description as it is written, then argparse's help (usage, options)."""
        return f"{self.description_text}\n\n{super().format_help()}"

    def _check_value(self, action: argparse.Action, value: object) -> None:
        """
        argparse's check of a value against its option's choices; an unknown ``--algo`` is one line with the close
        names (argparse's own error prints the whole usage and every name).

        argparse has no public hook for this check: should a Python release rename the method, an unknown ``--algo``
        gets argparse's own error again (tests/test_cli_first_minutes.py would say so).

        :param action: the option
        :param value: the value given
        """
        if action.dest == "algo" and action.choices is not None and value not in action.choices:
            names = [str(choice) for choice in action.choices]
            # The class's name (``OffOnDQN``, ``QRDQN``) is the same name but for case and underscores: it comes first
            same = [name for name in names if squeezed(name) == squeezed(str(value))]
            similar = difflib.get_close_matches(str(value), names, n=3, cutoff=0.6)
            close = (same + [name for name in similar if name not in same])[:3]
            hint = f"close matches: {', '.join(close)}" if close else "no name is close to it"
            self.exit(2, f"{self.prog}: error: unknown --algo '{value}'; {hint} (--help lists them all)\n")
        super()._check_value(action, value)


def squeezed(name: str) -> str:
    """``name`` in lower case without underscores, hyphens or other punctuation: ``OffOnDQN`` and ``offon_dqn`` alike."""
    return re.sub(r"[^a-z0-9]", "", name.lower())


def describe_help(module: ModuleType, algos: dict[str, type], summaries: dict[str, str] | None = None) -> None:
    """
    Make ``module`` (``rl_zoo3.train``) build its parser with :class:`DescribedArgumentParser`.

    The zoo calls ``argparse.ArgumentParser()`` inside ``train()``: the module's ``argparse`` is replaced by a
    namespace holding everything of ``argparse`` but this one class.

    :param module: the zoo module whose parser gets the description
    :param algos: the names to list (read when this is called, so that every registered name appears)
    :param summaries: a line on what each name trains
    """
    description = help_description(algos, summaries)
    parser_class = type("DescribedArgumentParser", (DescribedArgumentParser,), {"description_text": description})
    module.argparse = SimpleNamespace(**{**vars(argparse), "ArgumentParser": parser_class})  # type: ignore[attr-defined]


def _raised_by_this_package(error: BaseException) -> bool:
    frames = traceback.extract_tb(error.__traceback__)
    return bool(frames) and Path(frames[-1].filename).resolve().is_relative_to(PACKAGE_DIR)


@contextmanager
def unknown_env_in_one_line() -> Iterator[None]:
    """
    Turn the zoo's error for an env id that no package registered into one line on stderr, with the closest registered
    ids, and exit status 2 (the zoo raises a ``ValueError`` whose traceback ends in "you maybe meant ...").

    :raises SystemExit: with status 2, after printing the line
    """
    try:
        yield
    except ValueError as error:
        match = UNKNOWN_ENV.match(str(error))
        if match is None:
            raise
        import difflib

        import gymnasium as gym

        env_id = match.group("env")
        close = difflib.get_close_matches(env_id, list(gym.registry), n=3, cutoff=0.6)
        hint = f"; close matches: {', '.join(close)}" if close else "; no registered id is close to it"
        print(f"{prog()}: error: unknown environment '{env_id}'{hint}", file=sys.stderr)
        raise SystemExit(2) from None


@contextmanager
def argument_errors_in_one_line() -> Iterator[None]:
    """
    Turn an invalid value of one of OffOnDQN's arguments into one line on stderr and exit status 2 (as argparse).

    Only the errors of the package's own argument checks (a ``ValueError`` raised in this package, worded
    "`name` must be ..."); every other error keeps its traceback.

    :raises SystemExit: with status 2, after printing the line
    """
    try:
        yield
    except ValueError as error:
        match = ARGUMENT_ERROR.match(str(error))
        if match is None or not _raised_by_this_package(error):
            raise
        print(f"{prog()}: error: invalid hyperparameter (--hyperparams or the YAML file): {error}", file=sys.stderr)
        raise SystemExit(2) from None


@contextmanager
def warnings_in_one_line(categories: tuple[type[Warning], ...]) -> Iterator[None]:
    """
    Show the warnings of ``categories`` as one line on stderr, "<prog>: warning: ...", as the command line's errors are
    shown (Python's own format adds the file, line and source of the call, which are no help to the user); other
    warnings as Python shows them.

    :param categories: the warning classes to show so
    """
    shown = warnings.showwarning

    def show(message: Warning | str, category: type[Warning], *location: object, **keywords: object) -> None:
        if issubclass(category, categories):
            print(f"{prog()}: warning: {message}", file=sys.stderr)
        else:
            shown(message, category, *location, **keywords)  # type: ignore[arg-type]

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = shown


def resume_command(argv: list[str], folder: str | Path) -> str:
    """
    The command that goes on with an interrupted run: its own, with ``--resume folder`` in place of its
    ``--checkpoint-dir`` and ``--resume`` (a resumed run checkpoints into the folder it resumes from), quoted for a
    POSIX shell.

    :param argv: the interrupted command's arguments, as typed (without the program name)
    :param folder: the folder of its checkpoints
    :return: the command line
    """
    kept: list[str] = []
    skip = False
    for argument in argv:
        if skip:
            skip = False
        elif argument in ("--resume", "--checkpoint-dir"):
            skip = True
        elif not argument.startswith(("--resume=", "--checkpoint-dir=")):
            kept.append(argument)
    return shlex.join([*shlex.split(prog()), *kept, "--resume", str(folder)])


def interrupted_by_sigterm(interruption: KeyboardInterrupt) -> bool:
    """Whether SIGTERM stopped the run (:mod:`sb3_offon.termination`), not Ctrl-C."""
    from sb3_offon.termination import Terminated

    return isinstance(interruption, Terminated) or bool(getattr(interruption, "terminated", False))


def interruption_line(argv: list[str], interruption: KeyboardInterrupt) -> str:
    """
    What the command line says when Ctrl-C or SIGTERM stopped it: the step it reached, and either the newest complete
    checkpoint on disk with the command that goes on from it, or that there is none to resume from.

    :param argv: the command's arguments, as typed (without the program name)
    :param interruption: the interruption; a :class:`sb3_offon.zoo_checks.RunInterrupted` (training was stopped, and the zoo
        saved the model) says where the run's checkpoints are, another one (before or after training) is looked up in
        ``--checkpoint-dir`` or ``--resume``
    :return: the line, without its newline
    """
    from sb3_offon.resume import checkpoint_folders, checkpoint_problem
    from sb3_offon.zoo_checks import RunInterrupted, checkpoint_folder

    how = "stopped (SIGTERM)" if interrupted_by_sigterm(interruption) else "interrupted (Ctrl-C)"
    if isinstance(interruption, RunInterrupted):
        folder = interruption.checkpoint_dir
        where = f"at step {interruption.num_timesteps} of {interruption.budget}"
        saved = f"; the model trained so far is saved in {interruption.save_path}"
    else:
        known = argparse.ArgumentParser(add_help=False)
        known.add_argument("--checkpoint-dir")
        known.add_argument("--resume")
        options, _ = known.parse_known_args(argv)
        folder = options.checkpoint_dir or checkpoint_folder(options.resume)
        # Ctrl-C in training reaches here as RunInterrupted (the zoo's manager): this one came in the setup, the
        # evaluation after training or the saving
        where, saved = "while the run was set up, evaluated after training or saved", ""
    if folder is not None:
        # The newest complete one, the one --resume takes (a checkpoint being written when Ctrl-C came is not)
        newest = next((path for path in checkpoint_folders(folder) if checkpoint_problem(path) is None), None)
        if newest is not None:
            return (
                f"{prog()}: {how} {where}; newest checkpoint: step {newest.name} in {folder}; to go on "
                f"from it: {resume_command(argv, folder)}"
            )
    if not isinstance(interruption, RunInterrupted):
        why = ""
    elif interruption.checkpoint_freq > 0:
        why = f", before its first checkpoint (--checkpoint-freq {interruption.checkpoint_freq})"
    else:
        why = ", without checkpoints (--checkpoint-freq STEPS writes them)"
    return f"{prog()}: {how} {where}{why}: no checkpoint to resume from{saved}"


@contextmanager
def run_errors_in_one_line(
    usage_errors: tuple[type[BaseException], ...], run_errors: tuple[type[BaseException], ...], command: str = "train"
) -> Iterator[None]:
    """
    Turn the errors that say what to change in a line (an unknown hyperparameter, a checkpoint that cannot be resumed,
    a non-finite reward or loss, MinAtar not installed) into that line on stderr: exit status 2 for ``usage_errors``
    (as argparse's), 1 for ``run_errors`` (the run failed).

    :param usage_errors: the errors of the command as typed
    :param run_errors: the errors of the run
    :param command: the command whose name the line starts with (see :func:`prog`)
    :raises SystemExit: after printing the line
    """
    try:
        yield
    except usage_errors as error:
        print(f"{prog(command)}: error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    except run_errors as error:
        print(f"{prog(command)}: error: {error}", file=sys.stderr)
        raise SystemExit(1) from None


def main() -> int:
    """
    Register the algorithms, then run the zoo's command line on ``sys.argv``.

    :return: the exit status: 0, or 130 when Ctrl-C stopped the command and 143 when SIGTERM did (after one line on
        stderr, see :func:`interruption_line`; the zoo has saved the model trained so far when it stopped training; with
        checkpoints, SIGTERM in training stops at the next rollout start with a checkpoint of that step,
        :mod:`sb3_offon.termination`). Errors exit through ``SystemExit``
    """
    # Imported here, not at the top: without the zoo extra, a one-line hint instead of a traceback
    with zoo_required():
        import rl_zoo3.train as zoo_train

        from sb3_offon.cli_args import use_tolerant_store_dict
        from sb3_offon.common.non_finite import NonFiniteError
        from sb3_offon.minatar_envs import MinAtarNotInstalledError
        from sb3_offon.resume import CheckpointError
        from sb3_offon.termination import TERMINATED, sigterm_stops_the_run
        from sb3_offon.zoo import ALGO_SUMMARIES, ALGOS, register
        from sb3_offon.zoo_checks import (
            AtariSettingsNote,
            DefaultHyperparametersWarning,
            HyperparameterError,
            UnknownHyperparameterError,
            UnsupportedActionSpaceError,
        )
    register()
    describe_help(zoo_train, ALGOS, ALGO_SUMMARIES)
    # ``--hyperparams mc_mixing:convex``: unquoted strings (the zoo alone needs "mc_mixing:'convex'")
    use_tolerant_store_dict()
    # As typed: what the command to go on after Ctrl-C repeats
    typed = sys.argv[1:]
    sys.argv[1:] = one_thread_by_default(typed)
    flush_denormals_unless_kept(sys.argv[1:])
    usage_errors = (UnknownHyperparameterError, HyperparameterError, CheckpointError, UnsupportedActionSpaceError)
    # A MinAtar id without MinAtar: the line names the extra to install (a missing extra, as for the zoo: status 1)
    one_line = run_errors_in_one_line(usage_errors, (NonFiniteError, MinAtarNotInstalledError))
    try:
        with sigterm_stops_the_run(), one_line, argument_errors_in_one_line(), unknown_env_in_one_line():
            with warnings_in_one_line((DefaultHyperparametersWarning, AtariSettingsNote)):
                zoo_train.train()
    except KeyboardInterrupt as interruption:
        print(interruption_line(typed, interruption), file=sys.stderr)
        return TERMINATED if interrupted_by_sigterm(interruption) else INTERRUPTED
    return 0


if __name__ == "__main__":
    sys.exit(main())
