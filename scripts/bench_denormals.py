"""
What denormal floats cost a run late in its training: gradient steps from a checkpoint with IEEE arithmetic and with
denormals flushed to zero (``torch.set_flush_denormal``, the command line's default), taking turns.

Each round loads the checkpoint afresh (a flushed round leaves no denormals in the optimizer state for the rounds after
it), seeds the global generators alike, and times ``train()``'s gradient steps in CPU time on one torch thread. The
parameters the two arithmetics reach from the same checkpoint are compared bit for bit.

Any checkpoint of ``python -m sb3_offon.train --checkpoint-freq`` serves (a folder with ``model.zip`` and
``replay_buffer.pkl``, as ``scripts/benchmark.py`` keeps them under ``<root>/.checkpoints/`` while a run goes on)::

    python scripts/bench_denormals.py results/raw/.checkpoints/minatar/qrdqn/MinAtar-Asterix-v0_41/900000 --algo qrdqn
"""

import argparse
import json
import platform
import random
import subprocess
import time
from pathlib import Path
from typing import cast

import numpy as np
import stable_baselines3
import torch as th
from stable_baselines3 import DQN
from stable_baselines3.common.logger import configure
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

import sb3_offon
from sb3_offon.zoo import ALGOS

# The algorithms a checkpoint may hold: this package's (dqn_nstep is SB3's DQN, qrdqn sb3-contrib's QR-DQN with a faster
# loss) and the zoo's DQN
CLASSES: dict[str, type[OffPolicyAlgorithm]] = {
    "dqn": DQN,
    **{name: cast(type[OffPolicyAlgorithm], algo) for name, algo in ALGOS.items() if issubclass(algo, OffPolicyAlgorithm)},
}
# The smallest normal float32: below it (and above 0) a float is denormal
SMALLEST_NORMAL = float(np.finfo(np.float32).tiny)


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a checkpoint folder (model.zip, replay_buffer.pkl)")
    parser.add_argument("--algo", required=True, choices=sorted(CLASSES), help="the algorithm that wrote it")
    parser.add_argument("--gradient-steps", type=int, default=1000, help="timed gradient steps per round (default: 1000)")
    parser.add_argument("--pairs", type=int, default=3, help="pairs of rounds, the first of each pair alternating")
    parser.add_argument("--batch-size", type=int, default=None, help="default: the model's")
    parser.add_argument("--output", type=Path, default=Path("results/speed"), help="folder of the .md and .json")
    parser.add_argument("--name", default=None, help="file name (default: denormals_<algo>_<run>_<step>)")
    return parser.parse_args()


def load(args: argparse.Namespace) -> OffPolicyAlgorithm:
    """The checkpointed model and its replay buffer, with a logger that writes nothing."""
    model = CLASSES[args.algo].load(args.checkpoint / "model.zip", device="cpu")
    model.load_replay_buffer(args.checkpoint / "replay_buffer.pkl")
    model.set_logger(configure(folder=None, format_strings=[]))
    return model


def denormal_entries(model: OffPolicyAlgorithm) -> tuple[int, int]:
    """The optimizer state's float entries that are denormal (strictly between 0 and the smallest normal), and all."""
    denormal, total = 0, 0
    for state in model.policy.optimizer.state.values():
        for value in state.values():
            if th.is_tensor(value) and value.is_floating_point() and value.dim() > 0:
                magnitude = value.abs()
                denormal += int(((magnitude > 0) & (magnitude < SMALLEST_NORMAL)).sum())
                total += value.numel()
    return denormal, total


def timed_round(args: argparse.Namespace, flush: bool) -> tuple[float, dict[str, th.Tensor]]:
    """Milliseconds of CPU time per gradient step from the checkpoint, and the parameters reached."""
    model = load(args)
    batch_size = args.batch_size or model.batch_size
    random.seed(0)
    np.random.seed(0)
    th.manual_seed(0)
    th.set_flush_denormal(flush)
    try:
        start = time.process_time()
        model.train(gradient_steps=args.gradient_steps, batch_size=batch_size)
        elapsed = time.process_time() - start
    finally:
        th.set_flush_denormal(False)
    return elapsed / args.gradient_steps * 1e3, model.policy.state_dict()


def main() -> None:
    args = parse_args()
    th.set_num_threads(1)
    if not th.set_flush_denormal(False):
        raise SystemExit("This CPU has no flush-to-zero mode: nothing to compare")
    state_file = args.checkpoint / "checkpoint.json"
    step = json.loads(state_file.read_text())["num_timesteps"] if state_file.is_file() else "unknown"
    run = args.checkpoint.resolve().parent.name  # benchmark.py's checkpoints sit in <env>_<seed>/<step>/
    denormal, total = denormal_entries(load(args))
    share = denormal / max(total, 1)
    rows, identical = [], True
    for pair in range(args.pairs):
        order = [False, True] if pair % 2 == 0 else [True, False]
        times, parameters = {}, {}
        for flush in order:
            times[flush], parameters[flush] = timed_round(args, flush)
        identical &= all(th.equal(parameters[False][name], parameters[True][name]) for name in parameters[False])
        rows.append({"pair": pair, "ieee_first": order[0] is False, "ieee_ms": times[False], "flushed_ms": times[True]})
    medians = {key: float(np.median([row[key] for row in rows])) for key in ("ieee_ms", "flushed_ms")}
    speedup = medians["ieee_ms"] / medians["flushed_ms"]
    commit = subprocess.run(  # the commit measured, "+dirty" when the working tree has changes
        ["git", "describe", "--always", "--dirty=+dirty"], capture_output=True, text=True, cwd=Path(__file__).parent
    ).stdout.strip()
    versions = {
        "sb3_offon": commit or sb3_offon.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "torch": th.__version__,
        "machine": platform.machine(),
    }
    record = {
        "checkpoint": str(args.checkpoint),
        "algo": args.algo,
        "run": run,
        "num_timesteps": step,
        "denormal_share_of_optimizer_state": share,
        "gradient_steps_per_round": args.gradient_steps,
        "rows": rows,
        "median_ms": medians,
        "speedup": speedup,
        "parameters_identical": identical,
        "versions": versions,
    }
    lines = [
        f"{args.algo}, run {run}, checkpoint at step {step}: {share:.1%} of its optimizer state denormal. "
        f"{args.gradient_steps} gradient steps per round from the checkpoint, {args.pairs} pairs taking turns, CPU time, "
        f"1 torch thread, {versions['machine']}, sb3_offon {versions['sb3_offon']}, SB3 {versions['stable_baselines3']}, "
        f"torch {versions['torch']}",
        "",
        "| pair | first | IEEE ms/step | flushed ms/step | ratio |",
        "|---:|---|---:|---:|---:|",
        *(
            f"| {row['pair']} | {'IEEE' if row['ieee_first'] else 'flushed'} | {row['ieee_ms']:.2f} | "
            f"{row['flushed_ms']:.2f} | {row['ieee_ms'] / row['flushed_ms']:.2f} |"
            for row in rows
        ),
        f"| **median** | | **{medians['ieee_ms']:.2f}** | **{medians['flushed_ms']:.2f}** | **{speedup:.2f}** |",
        "",
        f"Parameters after {args.gradient_steps} gradient steps, IEEE against flushed, every pair: "
        + ("bit-identical." if identical else "**different**."),
    ]
    name = args.name or f"denormals_{args.algo}_{run}_{step}"
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / f"{name}.json").write_text(json.dumps(record, indent=2) + "\n")
    (args.output / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
