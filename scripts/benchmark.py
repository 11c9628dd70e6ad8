"""
Benchmark runner: a grid of algorithms x environments x seeds, each run being ``python -m sb3_offon.train``.

Every run goes through the same code path as the command line (rl-baselines3-zoo's ``train`` with the sb3_offon
algorithms registered), in its own subprocess: the zoo's ``train()`` parses ``sys.argv`` and holds global state, and a
subprocess keeps runs isolated and makes a crash visible as a return code. Each run trains with one torch thread on the
CPU (``--threads`` for more) and evaluates the deterministic policy every ``--eval-freq`` steps (the zoo's ``EvalCallback``).

Hyperparameter sets: ``--set tuned`` reads the bundled ``hyperparams/{algo}.yml`` (the zoo's tuned DQN settings for
every variant), ``--set paper`` the paper's settings in ``hyperparams/paper/{algo}.yml`` (``-conf paper``).

Output, in the zoo's layout ``{log folder}/{algo}/{env}_{run id}`` with the seed as run id (so that
``python -m rl_zoo3.plots.plot_train -f <root>/<set> ...`` reads it too)::

    <root>/<set>/<algo>/<env>_<seed>/
        0.monitor.csv          training episodes (r, l, t; plus goal_reached on MountainCarGoalBonus-v0)
        evaluations.npz        periodic deterministic evaluations (timesteps, results, ep_lengths)
        <env>/config.yml       the hyperparameters used; args.yml, command.txt: the zoo's record of the command
        train.log              the tail of the run's output
        done.json              the finished marker: spec, return code, wall time, host, the commit it started from

Only these small files are kept: the model zips (final and best) and replay buffers stay in the run's scratch folder,
which is deleted. A run is *finished* when ``done.json`` exists, its return code is 0 and ``evaluations.npz`` holds the
number of evaluations it records; finished runs are skipped, any other run folder (a crash, an interrupted grid, a
deleted file) is wiped and redone. A finished run made with other settings (budget, evaluation, ``--hyperparams``)
stops the runner before anything starts, unless ``--force`` redoes it.

Interrupted runs resume: each run writes a checkpoint at every evaluation (``--checkpoint-freq``, see
:mod:`sb3_offon.resume`) into ``<root>/.checkpoints/<grid>/<algo>/<env>_<seed>/``, and a run that finds one made with
its settings goes on from it (``--resume``) instead of starting again; ``done.json`` then lists the steps it resumed at
(``resumed_at``) and the commit each part started from (``code_version.commits``, kept beside the checkpoints in
``commits.json``). The checkpoint is removed when the run finishes. With ``--ray-address`` (a cluster) runs write no
checkpoints unless ``--checkpoint-freq`` asks for them, and then on the node that ran them.

The task function :func:`run_one` runs the command in a fresh temporary folder and returns the kept files as bytes;
the driver writes them, so a Ray cluster needs no shared file system (only ``sb3_offon`` installed on every node).
Locally, a pool of ``--workers`` threads (default: all cores) each waits on one training subprocess; with ``--ray``
the same function becomes a Ray task (one CPU each), on a local Ray instance or, with ``--ray-address``, on a cluster.

SIGTERM (``kill``, a batch scheduler's time limit) stops the local pool without losing training: no further run starts,
each running run gets the signal and stops at its next rollout start with a checkpoint of that step
(:mod:`sb3_offon.termination`), and the runner exits with status 143 once they have. A run stopped so is not recorded
(neither ``done.json`` nor ``failed.json``): the same command resumes it from that checkpoint.

Usage::

    # a study stated as a file (benchmarks/): its grid, resumed where it stopped; then its report
    python scripts/benchmark.py --study benchmarks/headtohead2.yml --workers 2
    python scripts/study.py benchmarks/headtohead2.yml
    # the paper's settings, Figures 8, 10, 12: CartPole-v1, MountainCar-v0, LunarLander-v3, four variants, 10 seeds
    python scripts/benchmark.py --set paper
    # the tuned settings (also Acrobot-v1)
    python scripts/benchmark.py --set tuned
    # Section 4.4
    python scripts/benchmark.py --set paper --envs CartPoleFallPenalty-v1 MountainCarGoalBonus-v0
    # a grid of its own on fresh seeds, in <root>/headtohead/{algo}/{env}_{seed}/ (the first head-to-head)
    python scripts/benchmark.py --set tuned --name headtohead --algos dqn dqn_nstep qrdqn --seeds 10-19
    # on a Ray cluster
    python scripts/benchmark.py --set paper --ray-address auto
"""

import argparse
import concurrent.futures
import importlib.metadata
import os
import platform
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import IO

from tqdm import tqdm

# run_records.py, grid_specs.py and study_file.py sit next to this script: importable however it is started (as a
# script, or loaded from its path)
sys.path.insert(0, str(Path(__file__).resolve().parent))
from grid_specs import available_sets, build_specs, candidate_specs, hyperparams_dir, parse_seeds, seeds_text
from run_records import (
    IDENTITY,
    STOPPED_FILE,
    claim,
    env_folder,
    read_evaluations,
    record_start,
    release,
    resume_point,
    run_dir,
    run_status,
    start_checkpoints,
    stopped_at,
    store,
)
from study_file import Study

ALGOS = ["offon_paper", "dqn_mc", "dqn_sarsa", "dqn"]
# The paper's Figures 8, 10 and 12; the tuned set also has the zoo's Acrobot-v1 entry
DEFAULT_ENVS = {
    "paper": ["CartPole-v1", "MountainCar-v0", "LunarLander-v3"],
    "tuned": ["CartPole-v1", "MountainCar-v0", "LunarLander-v3", "Acrobot-v1"],
}
# Files of the zoo's run folder worth keeping (small); model zips and replay buffers are not
KEEP_SUFFIXES = {".csv", ".npz", ".yml", ".yaml", ".txt", ".json"}
KEEP_NAMES = {"vecnormalize.pkl", STOPPED_FILE}
LOG_TAIL_LINES = 60
# The return codes of a training process that SIGTERM stopped: 143 once the command line's handler has written its
# checkpoint, -15 when the signal came before the handler was set (the process had just started)
SIGTERM_RETURN_CODES = {128 + signal.SIGTERM, -signal.SIGTERM}


class RunningProcesses:
    """
    The local pool's training processes now running, for SIGTERM to reach (:meth:`stop`), and whether the runner is
    stopping. Passed to :func:`run_one` as an argument, not read as a global: Ray pickles the task function with the
    globals it reads, and a lock cannot be pickled.
    """

    def __init__(self) -> None:
        self.processes: set[subprocess.Popen] = set()
        self.lock = threading.Lock()
        self.stopping = threading.Event()

    def add(self, process: subprocess.Popen) -> None:
        with self.lock:
            self.processes.add(process)
        if self.stopping.is_set():  # the runner began to stop while this one started: it stops too
            process.send_signal(signal.SIGTERM)

    def discard(self, process: subprocess.Popen) -> None:
        with self.lock:
            self.processes.discard(process)

    def stop(self, signum: int, frame: object) -> None:
        """The runner's SIGTERM handler: no further run starts, and the running ones are asked to stop (SIGTERM each)."""
        self.stopping.set()
        with self.lock:
            processes = list(self.processes)
        for process in processes:
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)


LOCAL_RUNS = RunningProcesses()


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument(
        "--study",
        type=Path,
        default=None,
        help="a study file (benchmarks/<study>.yml): its settings, algos, envs, seeds, evaluation and folder; --algos, "
        "--envs and --seeds then narrow it (e.g. one algorithm last)",
    )
    parser.add_argument("--set", default="paper", choices=available_sets(), help="hyperparameter set (default: paper)")
    parser.add_argument("--algos", nargs="+", default=None, help=f"algorithms (default: {' '.join(ALGOS)})")
    parser.add_argument("--envs", nargs="+", default=None, help="env ids (default: the set's benchmark envs)")
    parser.add_argument("--seeds", nargs="+", default=None, help="a count (10: seeds 0-9), a list (0 3 7) or a range (5-9)")
    parser.add_argument("-n", "--n-timesteps", type=int, default=None, help="override the budget of every run (tests)")
    parser.add_argument("--eval-freq", type=int, default=None, help="env steps between evaluations (default: budget / 20)")
    parser.add_argument("--n-evals", type=int, default=20, help="evaluations per run when --eval-freq is not given")
    parser.add_argument("--eval-episodes", type=int, default=10, help="episodes per evaluation (default: 10)")
    parser.add_argument(
        "--hyperparams", nargs="+", default=[], help="extra overrides passed to the zoo, e.g. learning_starts:100"
    )
    parser.add_argument("--root", type=Path, default=Path("results/raw"), help="results root (default: results/raw)")
    parser.add_argument(
        "--name",
        default=None,
        help="folder of this grid under --root (default: the set's name); e.g. --set tuned --name headtohead --seeds 10-19",
    )
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="parallel runs (default: all cores)")
    parser.add_argument("--ray", action="store_true", help="run the tasks on Ray (a local instance unless --ray-address)")
    parser.add_argument("--ray-address", default=None, help="join this Ray cluster ('auto', 'ray://host:10001', ...)")
    parser.add_argument(
        "--device",
        default=None,
        help="torch device of the runs (default: cpu for MlpPolicy runs, where one thread each beats a shared GPU; "
        "auto, the GPU if there is one, for CNN and other policies)",
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads of each run (default: 1, one core a run; more shortens a run that must end within a "
        "time limit, such as QR-DQN on LunarLander-v3, at some cost in throughput)",
    )
    parser.add_argument("--timeout", type=float, default=None, help="seconds after which a run is killed (and failed)")
    parser.add_argument(
        "--checkpoint-freq",
        type=int,
        default=None,
        help="env steps between the checkpoints an interrupted run resumes from (default: every evaluation; none with "
        "--ray-address; 0: none). A checkpoint holds the replay buffer (80-200 MB for MinAtar's): checkpoint less often "
        "where buffers are large",
    )
    parser.add_argument("--force", action="store_true", help="redo finished runs that were made with other settings")
    parser.add_argument("--dry-run", action="store_true", help="list the runs and their commands, run nothing")
    args = parser.parse_args(argv)
    args.run_names, args.candidates, args.study_file, args.seeds_given = {}, {}, None, False
    if args.study is not None:
        from_study(args, parser)
    args.algos = args.algos or ALGOS
    args.seeds = parse_seeds(args.seeds or ["10"])
    args.envs = args.envs or DEFAULT_ENVS.get(args.set, DEFAULT_ENVS["paper"])
    args.ray = args.ray or args.ray_address is not None
    if args.checkpoint_freq is None and args.ray_address is not None:
        args.checkpoint_freq = 0  # the nodes of a cluster may not share the driver's disk
    return args


def from_study(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """The grid of a study file (read as ``scripts/study.py`` reads it: ``study_file.Study``), narrowed by --algos, --envs
    and --seeds."""
    study = Study.read(args.study)
    for option, key, given, listed in (
        ("--algos", "algos", args.algos, study.algos),
        ("--envs", "envs", args.envs, study.envs),
        ("--seeds", "seeds", parse_seeds(args.seeds) if args.seeds else None, study.seeds),
    ):
        if given and not set(given) <= set(listed):
            parser.error(f"{option} {' '.join(map(str, given))}: not in the study's {key} {listed}")
    args.study_file, args.seeds_given = study, bool(args.seeds)
    args.set, args.name = study.settings, study.folder
    args.algos = args.algos or list(study.algos)
    args.envs = args.envs or list(study.envs)
    args.seeds = args.seeds or [f"{seed}-{seed}" for seed in study.seeds]
    args.eval_freq = args.eval_freq or study.evaluation_every
    args.eval_episodes = study.evaluation_episodes or args.eval_episodes
    args.device = args.device or study.device
    args.run_names, args.candidates = dict(study.run_names), dict(study.candidates)


def run_threads(spec: dict) -> str:
    """The torch threads of a run (specs of runs made before ``--threads`` existed have none: one thread)."""
    return str(spec.get("threads", 1))


def train_command(spec: dict, log_folder: str) -> list[str]:
    """The ``python -m sb3_offon.train`` command of a run (without the interpreter)."""
    command = ["-m", "sb3_offon.train", "--algo", spec["algo"], "--env", spec["env"], "--seed", str(spec["seed"])]
    command += ["-f", log_folder, "-n", str(spec["n_timesteps"]), "--eval-freq", str(spec["eval_freq"])]
    command += ["--eval-episodes", str(spec["eval_episodes"]), "--num-threads", run_threads(spec), "--device", spec["device"]]
    if spec["set"] != "tuned":  # tuned: the bundled {algo}.yml is sb3_offon.train's default
        command += ["-conf", spec["set"]]
    if spec.get("checkpoint_dir"):
        command += ["--checkpoint-freq", str(spec["checkpoint_freq"]), "--checkpoint-dir", spec["checkpoint_dir"]]
    if spec["hyperparams"]:
        command += ["--hyperparams", *spec["hyperparams"]]
    return command


# ----------------------------------------------------------------------------------------------------------------------
# The task function: the same for the local pool and for Ray
# ----------------------------------------------------------------------------------------------------------------------
def run_one(spec: dict, running: RunningProcesses | None = None) -> dict:
    """
    Train one run in a fresh scratch folder and return its kept files.

    The scratch folder of a run that checkpoints sits next to its checkpoints (``<checkpoint folder>.scratch``), so that
    a run cut off leaves it where the next attempt empties it; otherwise it is a temporary folder.

    :param spec: a run of :func:`build_specs`
    :param running: where the local pool lists its training processes for SIGTERM to reach (None: not listed)
    :return: ``spec``, ``returncode`` (None when the command could not start or timed out), ``wall_time_s`` (of this
        part, for a resumed run), ``started``/``finished`` (UTC, ISO 8601), ``host``, ``command``, ``resumed_at`` (the
        steps it resumed at, if any), ``code_version`` (the commit this part started from, and each part's) and ``files``
        (relative path -> bytes: the zoo's run folder without models and replay buffers, plus ``train.log``, the tail of
        the output)
    """
    if spec.get("checkpoint_dir"):
        scratch = Path(f"{spec['checkpoint_dir']}.scratch")
        shutil.rmtree(scratch, ignore_errors=True)
        scratch.mkdir(parents=True)
    else:
        scratch = Path(tempfile.mkdtemp(prefix=f"offon_{spec['algo']}_{env_folder(spec['env'])}_{spec['seed']}_"))
    command = train_command(spec, "logs")
    resumed_at = resume_point(spec)
    if resumed_at:
        command += ["--resume", spec["checkpoint_dir"]]
    elif spec.get("checkpoint_dir"):
        start_checkpoints(Path(spec["checkpoint_dir"]), spec)
    # The code this part of the run starts from, and with checkpoints each earlier part's (kept beside them)
    commit = checkout_commit()
    commits = record_start(Path(spec["checkpoint_dir"]), commit, len(resumed_at)) if spec.get("checkpoint_dir") else [commit]
    # The run's threads, already at import time (torch.set_num_threads comes later, from --num-threads)
    threads = run_threads(spec)
    environment = {**os.environ, "OMP_NUM_THREADS": threads, "MKL_NUM_THREADS": threads}
    started, start = datetime.now(timezone.utc), time.perf_counter()
    returncode = None
    with open(scratch / "train.log", "w") as log:
        try:
            returncode = run_training([sys.executable, *command], scratch, log, environment, spec.get("timeout"), running)
        except (OSError, subprocess.TimeoutExpired) as error:
            log.write(f"\n[benchmark] {type(error).__name__}: {error}\n")
    wall_time = time.perf_counter() - start
    files: dict[str, bytes] = {}
    # The zoo writes logs/{algo}/{env}_1/ in the empty scratch folder
    zoo_runs = sorted((scratch / "logs" / spec["algo"]).glob(f"{env_folder(spec['env'])}_*"))
    if zoo_runs:
        for path in sorted(zoo_runs[-1].rglob("*")):
            if path.is_file() and (path.suffix in KEEP_SUFFIXES or path.name in KEEP_NAMES):
                files[path.relative_to(zoo_runs[-1]).as_posix()] = path.read_bytes()
    lines = (scratch / "train.log").read_text(errors="replace").splitlines()
    files["train.log"] = ("\n".join(lines[-LOG_TAIL_LINES:]) + "\n").encode()
    # A run cut short keeps its checkpoints for the next attempt, even where it exited with 0 (the zoo does on Ctrl-C)
    whole_way = zoo_runs and stopped_at(read_evaluations(zoo_runs[-1]), spec, (zoo_runs[-1] / STOPPED_FILE).is_file()) is None
    shutil.rmtree(scratch, ignore_errors=True)
    if returncode == 0 and whole_way and spec.get("checkpoint_dir"):
        shutil.rmtree(spec["checkpoint_dir"], ignore_errors=True)
    return {
        "spec": {key: value for key, value in spec.items() if key != "checkpoint_dir"},  # a path of this machine
        **({"resumed_at": resumed_at} if resumed_at else {}),
        "code_version": {"commit": commit, "commits": commits},  # completed by the driver (run_code_version)
        "returncode": returncode,
        "wall_time_s": round(wall_time, 2),
        "started": started.isoformat(timespec="seconds"),
        "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "host": socket.gethostname(),
        "versions": library_versions(),
        "command": ["python", *command],
        "files": files,
    }


def run_training(
    command: list[str],
    cwd: Path,
    log: IO[str],
    environment: dict[str, str],
    timeout: float | None,
    running: RunningProcesses | None = None,
) -> int:
    """
    ``subprocess.run`` of a training command (its output into ``log``, killed after ``timeout`` seconds), the process
    listed in ``running`` while it runs so that the runner's SIGTERM reaches it.

    :return: its return code
    :raises subprocess.TimeoutExpired: after killing it, when it ran past ``timeout``
    """
    with subprocess.Popen(command, cwd=cwd, stdout=log, stderr=subprocess.STDOUT, env=environment) as process:
        if running is not None:
            running.add(process)
        try:
            return process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            raise
        finally:
            if running is not None:
                running.discard(process)


def stopped_by_sigterm(result: dict) -> bool:
    """Whether a run's training process ended because SIGTERM stopped it (its checkpoint kept for the next attempt)."""
    return result.get("returncode") in SIGTERM_RETURN_CODES


def library_versions() -> dict[str, str]:
    """Python and the libraries a run's numbers depend on, as installed where the run ran (read without importing)."""
    versions = {"python": platform.python_version()}
    for name in ("torch", "stable_baselines3", "gymnasium", "numpy"):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def checkout_commit() -> str | None:
    """
    The git commit of this checkout now (with ``-dirty`` for uncommitted changes to tracked files), None without git (a
    copy of the working tree without its git folder, another machine's scratch copy, say).
    """
    repository = hyperparams_dir().parent.parent

    def git(*command: str) -> str:
        return subprocess.run(["git", *command], cwd=repository, capture_output=True, text=True).stdout.strip()

    try:
        commit = git("rev-parse", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except OSError:
        return None
    return commit + ("-dirty" if dirty else "") if commit else None


_CODE_VERSION: dict[str, str] = {}


def code_version() -> dict[str, str]:
    """
    The driver's commit (:func:`checkout_commit`), read once: what a run records where its task could not read the
    commit it started from (a node without the git folder). Without git, the environment variable ``SB3_OFFON_COMMIT``
    names it, else it is ``"unknown"``.
    """
    if not _CODE_VERSION:
        _CODE_VERSION["commit"] = checkout_commit() or os.environ.get("SB3_OFFON_COMMIT", "unknown")
    return _CODE_VERSION


def run_code_version(result: dict) -> dict:
    """
    The code a run ran: the commit its subprocess started from (read as it started, not when the driver stores it:
    the checkout may have moved on in between), and for a resumed run ``commits``, the commit of each of its parts
    in order (``None`` for a part that recorded none). The driver's commit where the task read none.
    """
    started = result.get("code_version") or {}
    record = {"commit": started.get("commit") or code_version()["commit"]}
    if len(started.get("commits", [])) > 1:
        record["commits"] = started["commits"]
    return record


def run_order(specs: list[dict], envs: list[str] | None = None) -> list[dict]:
    """
    Seed by seed, within a seed the longest runs first, and among runs of one length env by env (every algorithm of
    an env, in the grid's order, before the next env).

    An interrupted grid then holds whole seeds (every algorithm and env of seeds 0..k), which compare fairly, rather
    than every seed of the first algorithms; within a seed, long runs first make the grid end sooner; and the runs of
    an env end close together, so that a seed half done already compares the algorithms on some envs.

    :param specs: the runs
    :param envs: the grid's envs in its order (default: as they first appear in ``specs``, which for the runs left of a
        grid begun is not the grid's order: an env whose first algorithms are finished would come last)
    """
    env_order = {env: index for index, env in enumerate(dict.fromkeys([*(envs or []), *(spec["env"] for spec in specs)]))}
    return sorted(specs, key=lambda spec: (spec["seed"], -spec["n_timesteps"], env_order[spec["env"]]))


# ----------------------------------------------------------------------------------------------------------------------
# Executors: both yield the results of run_one as the runs finish, and {"spec": ..., "skipped": True} for a run that
# another runner holds (or has finished meanwhile). Each run is claimed (run_records.claim) before it starts and given
# back when the caller asks for the next result, after it has stored this one.
# ----------------------------------------------------------------------------------------------------------------------
def take(root: Path, spec: dict) -> int | None:
    """Claim the run of ``spec`` and empty its folder (an unfinished one is redone, from its checkpoint if any)."""
    descriptor = claim(root, spec)
    if descriptor is not None:
        shutil.rmtree(run_dir(root, spec), ignore_errors=True)
    return descriptor


def run_local(specs: list[dict], workers: int, root: Path) -> Iterator[dict]:
    """A pool of threads, each waiting on one training subprocess: the work itself is in the subprocesses."""
    waiting, running = iter(specs), {}
    with concurrent.futures.ThreadPoolExecutor(max_workers=workers) as pool:

        def start_next() -> Iterator[dict]:
            for spec in waiting:
                if LOCAL_RUNS.stopping.is_set():  # SIGTERM: what has not started stays for the next runner
                    return
                descriptor = take(root, spec)
                if descriptor is None:
                    yield {"spec": spec, "skipped": True}
                    continue
                running[pool.submit(run_one, spec, LOCAL_RUNS)] = descriptor
                return

        try:
            for _ in range(workers):
                yield from start_next()
            while running:
                finished, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
                for future in finished:
                    descriptor = running.pop(future)
                    try:
                        yield future.result()
                    finally:
                        release(descriptor)
                    yield from start_next()
        finally:
            for future in running:
                future.cancel()


def run_ray(specs: list[dict], workers: int, address: str | None, root: Path) -> Iterator[dict]:
    """The same task function as a Ray task (1 CPU each), on a local Ray instance or on the cluster at ``address``."""
    import ray

    # Ray schedules every run at once: they are claimed up front (locks in this process; its tasks write nothing here)
    held: dict[int, int] = {}
    for spec in specs:
        descriptor = take(root, spec)
        if descriptor is None:
            yield {"spec": spec, "skipped": True}
        else:
            held[id(spec)] = descriptor
    specs = [spec for spec in specs if id(spec) in held]
    if address is None:
        ray.init(num_cpus=workers, include_dashboard=False)
    else:
        ray.init(address=address)
    # Imported as a module (``import benchmark``), run_one would be pickled by reference, and Ray's workers cannot
    # import a script: send it by value. (Run as a script, ``__main__`` is always sent by value.)
    if run_one.__module__ != "__main__":
        ray.cloudpickle.register_pickle_by_value(sys.modules[run_one.__module__])
    task = ray.remote(num_cpus=1, max_retries=0)(run_one)
    pending = {task.options(num_cpus=int(run_threads(spec))).remote(spec): spec for spec in specs}
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            spec = pending.pop(ready[0])
            try:
                result = ray.get(ready[0])
            except ray.exceptions.RayError as error:  # a lost worker or node: a failed run, redone next time
                message = f"[benchmark] Ray task failed: {error}\n".encode()
                result = {"spec": spec, "returncode": None, "wall_time_s": 0.0, "files": {"train.log": message}}
            try:
                yield result
            finally:
                release(held.pop(id(spec)))
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        ray.shutdown()
        for descriptor in held.values():
            release(descriptor)


# ----------------------------------------------------------------------------------------------------------------------
# Main
# ----------------------------------------------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    specs = candidate_specs(args) if args.candidates else build_specs(args)
    statuses = {id(spec): run_status(run_dir(args.root, spec), spec) for spec in specs}
    conflicts = [spec for spec in specs if statuses[id(spec)] == "conflict"]
    if conflicts and not args.force:
        listing = "\n  ".join(str(run_dir(args.root, spec)) for spec in conflicts)
        print(
            f"{len(conflicts)} finished run(s) were made with other settings ({', '.join(IDENTITY)}):\n  {listing}\n"
            "Use another --root, or --force to redo them.",
            file=sys.stderr,
        )
        return 2
    todo = [spec for spec in specs if statuses[id(spec)] != "finished"]
    todo = run_order(todo, args.envs)
    print(
        f"{len(specs)} runs ({len(args.algos)} {'candidates' if args.candidates else 'algos'} x {len(args.envs)} envs x "
        f"{len(args.seeds)} seeds "
        f"({seeds_text(args.seeds)}), '{args.set}' set) "
        f"in {args.root / (args.name or args.set) if not args.candidates else args.root}: "
        f"{len(specs) - len(todo)} finished, {len(todo)} to run"
        + (f" on Ray ({args.ray_address or f'local, {args.workers} CPUs'})" if args.ray else f" on {args.workers} workers")
    )
    if args.dry_run:
        for spec in todo:
            resumed_at = resume_point(spec)
            resume = f" (resumes at step {resumed_at[-1]})" if resumed_at else ""
            print(" ".join(["python", *train_command(spec, "<scratch>")]), "->", f"{run_dir(args.root, spec)}{resume}")
        return 0
    if not todo:
        return 0
    if args.ray:
        results = run_ray(todo, args.workers, args.ray_address, args.root)
    else:
        results = run_local(todo, args.workers, args.root)
        signal.signal(signal.SIGTERM, LOCAL_RUNS.stop)
    # The bar counts env steps (budgets), so that its ETA weighs long runs as such; the postfix counts runs
    bar = tqdm(total=sum(spec["n_timesteps"] for spec in todo), unit="step", unit_scale=True, dynamic_ncols=True)
    bar.set_postfix_str(f"0/{len(todo)} runs")
    wall_times, failures = [], 0
    with bar:
        for n_done, result in enumerate(results, start=1):
            spec = result["spec"]
            if result.get("skipped"):
                message = f"{spec['algo']} {spec['env']} seed {spec['seed']}: taken by another runner, left to it"
            elif stopped_by_sigterm(result):
                name = f"{spec['algo']} {spec['env']} seed {spec['seed']}"
                message = (
                    f"stopped {name} by SIGTERM after {result['wall_time_s']:.1f} s; its checkpoint is kept, and the "
                    "same command resumes it"
                )
            else:
                ok, message = store(result, run_dir(args.root, spec), run_code_version(result))
                failures += not ok
                if ok:
                    wall_times.append(result["wall_time_s"])
            bar.write(message)
            bar.update(spec["n_timesteps"])
            bar.set_postfix_str(f"{n_done}/{len(todo)} runs" + (f", {failures} failed" if failures else ""))
    if wall_times:
        print(
            f"Wall time per run: min {min(wall_times):.1f} s, median {statistics.median(wall_times):.1f} s, "
            f"max {max(wall_times):.1f} s ({len(wall_times)} runs)"
        )
    if failures:
        print(f"{failures} run(s) failed; run the same command again to redo them", file=sys.stderr)
    if LOCAL_RUNS.stopping.is_set():
        print("Stopped by SIGTERM; the same command goes on from the runs' checkpoints", file=sys.stderr)
        return 128 + signal.SIGTERM
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
