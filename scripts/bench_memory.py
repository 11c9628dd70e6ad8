"""
Memory benchmark: the resident memory of one training run, sampled every ``--every`` env steps, with a bundled
hyperparameter set (the Atari 100k settings by default), as the command line would train it.

The model and envs are built by the command line's experiment manager (``sb3_offon.zoo.OffOnExperimentManager``: the
same settings, wrappers and replay buffer as ``python -m sb3_offon.train``), without periodic evaluations; a callback
reads the process's resident set size (``/proc/self/statm``) every ``--every`` steps, and the peak is the kernel's
(``getrusage``). Runs of two algorithms started side by side (one per core) compare at equal steps.

Usage::

    python scripts/bench_memory.py --algo offon_dqn --env BoxingNoFrameskip-v4 --steps 30000 --output offon.json &
    python scripts/bench_memory.py --algo dqn --env BoxingNoFrameskip-v4 --steps 30000 --output dqn.json
"""

import argparse
import json
import os
import platform
import resource
import tempfile
import time
from pathlib import Path

import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_offon.zoo import OffOnExperimentManager, register


class ResidentMemory(BaseCallback):
    """Every ``every`` env steps: the step, the process's resident memory (Linux) and the wall time since the start."""

    def __init__(self, every: int) -> None:
        super().__init__()
        self.every = every
        self.samples: list[dict[str, float]] = []
        self.start = time.perf_counter()
        self.page_size = os.sysconf("SC_PAGE_SIZE")

    def _on_step(self) -> bool:
        if self.num_timesteps % self.every == 0:
            rss = int(Path("/proc/self/statm").read_text().split()[1]) * self.page_size
            self.samples.append({"step": self.num_timesteps, "rss_gb": rss / 1e9, "wall_s": time.perf_counter() - self.start})
        return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--algo", required=True, help="a --algo name of the command line (dqn, dqn_nstep, offon_dqn, ...)")
    parser.add_argument("--env", default="BoxingNoFrameskip-v4")
    parser.add_argument("--conf", default="atari100k", help="the bundled hyperparameter set (default: atari100k)")
    parser.add_argument("--steps", type=int, default=30_000, help="env steps to train")
    parser.add_argument("--every", type=int, default=1_000, help="env steps between samples")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=Path, required=True, help="JSON file of the samples")
    args = parser.parse_args()

    th.set_num_threads(1)
    register()
    with tempfile.TemporaryDirectory() as folder:
        namespace = argparse.Namespace(algo=args.algo, env=args.env, conf_file=None)
        manager = OffOnExperimentManager(
            namespace, args.algo, args.env, folder, n_timesteps=args.steps, eval_freq=-1, seed=args.seed, config=args.conf
        )
        model, _ = manager.setup_experiment()
        memory = ResidentMemory(args.every)
        model.learn(args.steps, callback=memory)
    record = {
        "algo": args.algo,
        "env": args.env,
        "conf": args.conf,
        "steps": args.steps,
        "seed": args.seed,
        "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9,  # Linux: KiB
        "samples": memory.samples,
        "host": platform.node(),
        "torch": th.__version__,
    }
    args.output.write_text(json.dumps(record, indent=1) + "\n")
    print(f"{args.algo} on {args.env}, {args.steps} steps: peak resident memory {record['peak_rss_gb']:.2f} GB")


if __name__ == "__main__":
    main()
