"""
The run folders of a grid (``scripts/benchmark.py``): where a run's folder and its checkpoints are, which runs are
finished, where an unfinished one resumes, and how a run's files and its record (``done.json`` or ``failed.json``) are
written.
"""

import fcntl
import json
import os
import shutil
import warnings
from pathlib import Path

import numpy as np

# The runs' own settings that define a result: a finished run made with other values is not the requested run
IDENTITY = ("n_timesteps", "eval_freq", "eval_episodes", "hyperparams")
DONE, FAILED = "done.json", "failed.json"
# What the command line writes into a run's log folder when the run's own stop rule ended it (sb3_offon.resume's
# STOPPED_FILE; named here so that the runner reads records without importing torch)
STOPPED_FILE = "stopped.json"


def env_folder(env: str) -> str:
    """An env id as a folder name, as the zoo writes it: ``MinAtar/Breakout-v0`` -> ``MinAtar-Breakout-v0``."""
    return env.replace("/", "-")


def run_dir(root: Path, spec: dict) -> Path:
    """``<root>/<grid>/<algo>/<env>_<seed>``; a study's ``run_names`` keep a renamed algorithm in its runs' folder."""
    folder = spec.get("run_name", spec["algo"])
    return root / spec.get("grid", spec["set"]) / folder / f"{env_folder(spec['env'])}_{spec['seed']}"


def checkpoint_dir(root: Path, spec: dict) -> Path:
    """Where a run's checkpoints go: ``<root>/.checkpoints/<grid>/<algo>/<env>_<seed>`` (a hidden folder git ignores)."""
    return root / ".checkpoints" / run_dir(root, spec).relative_to(root)


def claim(root: Path, spec: dict) -> int | None:
    """
    Take the run of ``spec`` for this process: an exclusive lock (``flock``) on ``<its checkpoint folder>.lock``, held
    until :func:`release`, so that two runners started on overlapping grids (or a grid started twice) never train,
    resume or store the same run at once. Runners on one machine, or on a file system with working ``flock``, see
    each other's locks.

    :return: the lock's file descriptor, or None when another process holds the run, or has finished it since this
        runner listed its runs (the lock is then not kept)
    """
    checkpoints = checkpoint_dir(root, spec)
    path = checkpoints.with_name(f"{checkpoints.name}.lock")
    path.parent.mkdir(parents=True, exist_ok=True)
    descriptor = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(descriptor)
        return None
    if run_status(run_dir(root, spec), spec) == "finished":
        release(descriptor)
        return None
    return descriptor


def release(descriptor: int) -> None:
    """Give back a run taken with :func:`claim`."""
    fcntl.flock(descriptor, fcntl.LOCK_UN)
    os.close(descriptor)


def checkpoint_settings(spec: dict) -> dict:
    """What a checkpoint must have been made with to be resumed by the run of ``spec``."""
    return {key: spec[key] for key in ("set", "algo", "env", "seed", *IDENTITY)}


def resume_point(spec: dict) -> list[int]:
    """
    The steps at which the run of ``spec`` has resumed so far, the one it would resume at now last: those of the newest
    complete checkpoint in its folder, the one ``--resume`` takes (:meth:`sb3_offon.resume.Checkpoint.latest`: a damaged
    newer one is passed over); ``[]`` when the run writes no checkpoints or has none complete made with its settings.
    """
    if not spec.get("checkpoint_dir"):
        return []
    folder = Path(spec["checkpoint_dir"])
    try:
        if json.loads((folder / "spec.json").read_text()) != checkpoint_settings(spec):
            return []
    except (OSError, ValueError):
        return []
    # Imported here, where a checkpoint exists: the rest of the records are read without importing torch
    from sb3_offon.resume import Checkpoint, CheckpointError

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the resumed run warns about the damaged checkpoints itself
        try:
            checkpoint = Checkpoint.latest(folder)
        except CheckpointError:
            return []
    return [*checkpoint.resumed_at, checkpoint.num_timesteps] if checkpoint is not None else []


def start_checkpoints(folder: Path, spec: dict) -> None:
    """Empty a run's checkpoint folder (it may hold another run's) and record the run's settings in it."""
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    (folder / "spec.json").write_text(json.dumps(checkpoint_settings(spec), indent=2) + "\n")


def record_start(folder: Path, commit: str | None, earlier_parts: int) -> list[str | None]:
    """
    Add the commit a part of a run starts from to its checkpoint folder's ``commits.json``; return the commits of the
    parts whose work the run goes on from, this one last.

    :param folder: the run's checkpoint folder
    :param commit: the commit this part starts from (None where none could be read)
    :param earlier_parts: how many parts the checkpoint it resumes from holds the work of (``len(resumed_at)``: 0 for a
        run that starts afresh); a part that left no checkpoint is dropped, one that started before the file was kept
        is ``None``
    """
    path = folder / "commits.json"
    try:
        commits = json.loads(path.read_text())[:earlier_parts]
    except (OSError, ValueError):
        commits = []
    commits = [*commits, *[None] * (earlier_parts - len(commits)), commit]
    folder.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(commits) + "\n")
    return commits


def read_evaluations(folder: Path) -> dict[str, np.ndarray] | None:
    try:
        with np.load(folder / "evaluations.npz") as data:
            return {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError):
        return None


def stopped_at(evaluations: dict[str, np.ndarray] | None, spec: dict, ended_by_its_rule: bool = False) -> int | None:
    """
    The step of the last evaluation of a run cut short before its budget, None for a run that went the whole way or
    that its own stop rule ended (``ended_by_its_rule``: its log folder has ``stopped.json``).

    A run that reached ``n_timesteps`` has evaluated within its last ``eval_freq`` steps; one whose last evaluation is
    older was cut short, whatever its return code (the zoo saves and exits with 0 on Ctrl-C), unless a callback of its
    settings ended it on purpose (the paper's CartPole stop rule), which the command line records in ``stopped.json``.
    """
    if ended_by_its_rule:
        return None
    if evaluations is None or len(evaluations.get("timesteps", [])) == 0:
        return 0
    last = int(evaluations["timesteps"][-1])
    return last if last + spec["eval_freq"] <= spec["n_timesteps"] else None


def run_status(folder: Path, spec: dict) -> str:
    """``"todo"`` (no folder, or an unfinished one), ``"finished"``, or ``"conflict"`` (finished with other settings)."""
    try:
        record = json.loads((folder / DONE).read_text())
    except (OSError, ValueError):
        return "todo"
    evaluations = read_evaluations(folder)
    if (
        record.get("returncode") != 0
        or evaluations is None
        or len(evaluations.get("timesteps", [])) != record.get("n_evaluations")
        or len(evaluations.get("results", [])) != record.get("n_evaluations")
        or not any(folder.glob("*monitor.csv"))
    ):
        return "todo"
    same = all(record["spec"].get(key) == spec[key] for key in IDENTITY)
    return "finished" if same else "conflict"


def store(result: dict, folder: Path, code_version: dict[str, str]) -> tuple[bool, str]:
    """
    Write a run's files into its folder, with ``done.json`` (or ``failed.json``) written last.

    The files are written into a hidden sibling folder that replaces the run folder at the end, so that an interrupted
    write never leaves a folder that looks finished.

    :param result: what the task function returned (its spec, return code, times, files as bytes, ...)
    :param folder: the run's folder
    :param code_version: the commit of the code that made the run, recorded with it
    :return: whether the run succeeded, and a one-line summary
    """
    spec, files = result["spec"], result["files"]
    partial = folder.with_name(f".{folder.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    for name, data in files.items():
        (partial / name).parent.mkdir(parents=True, exist_ok=True)
        (partial / name).write_bytes(data)
    evaluations = read_evaluations(partial) if "evaluations.npz" in files else None
    n_evaluations = 0 if evaluations is None else len(evaluations["timesteps"])
    stopped = stopped_at(evaluations, spec, STOPPED_FILE in files) if n_evaluations else None
    monitored = any(name.endswith("monitor.csv") for name in files)
    ok = result["returncode"] == 0 and n_evaluations > 0 and stopped is None and monitored
    record = {key: value for key, value in result.items() if key != "files"}
    record.update(n_evaluations=n_evaluations, files=sorted(files), code_version=code_version)
    if n_evaluations:
        record["last_evaluation"] = {
            "timestep": int(evaluations["timesteps"][-1]),
            "mean_return": float(np.mean(evaluations["results"][-1])),
        }
    (partial / (DONE if ok else FAILED)).write_text(json.dumps(record, indent=2) + "\n")
    shutil.rmtree(folder, ignore_errors=True)
    partial.rename(folder)
    name = f"{spec['algo']} {spec['env']} seed {spec['seed']}"
    if ok:
        last = record["last_evaluation"]["mean_return"]
        resumed = f" (resumed at step {', '.join(map(str, result['resumed_at']))})" if result.get("resumed_at") else ""
        return True, f"done   {name} in {result['wall_time_s']:.1f} s{resumed}, last evaluation {last:.1f}"
    if result["returncode"] != 0:
        reason = f"return code {result['returncode']}"
    elif stopped is not None:
        reason = f"stopped after its evaluation at step {stopped} of {spec['n_timesteps']}"
    else:
        reason = "no evaluation or monitor file"
    tail = "\n    ".join(files["train.log"].decode(errors="replace").splitlines()[-15:])
    return False, f"FAILED {name} ({reason}) after {result['wall_time_s']:.1f} s, see {folder / 'train.log'}:\n    {tail}"
