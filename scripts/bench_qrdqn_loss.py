"""
Speed benchmark: sb3_offon's QR-DQN (its quantile Huber loss from sorted targets) against sb3-contrib's QRDQN.

Two measurements, one thread, on MinAtar/Breakout-v0 with the MinAtar paper's DQN settings (as in
``scripts/bench_speed.py``) and QR-DQN's 200 quantiles:

1. the loss alone: forward and backward of a batch of 32 x 200 current quantiles against 32 x 200 targets, both
   functions taking turns ``--loss-rounds`` times, the milliseconds of each (median over rounds);
2. whole learn() calls: ``--repeats`` pairs of runs taking turns as in ``bench_speed.py`` (one process, the two runs
   hand a baton to each other, the pairs alternate which starts), ``--timesteps`` timed env steps after ``--prefill``
   untimed ones; env steps per second and the median of the pair ratios.

Usage:
    python scripts/bench_qrdqn_loss.py --repeats 3 --timesteps 10000 --output results/speed/qrdqn_loss_minatar.json
"""

import argparse
import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import sb3_contrib
import torch as th
from bench_speed import MINATAR_BREAKOUT, ZOO_HYPERPARAMS, ratio_summary, run_pair
from sb3_contrib.common.utils import quantile_huber_loss as sb3_contrib_loss

import sb3_offon
from sb3_offon.common.quantile_loss import quantile_huber_loss
from sb3_offon.qrdqn import QRDQN

# run_pair's two roles: "DQN" is the baseline (sb3-contrib's QRDQN), "OffOnDQN" the candidate (sb3_offon's)
CLASSES = {"DQN": sb3_contrib.QRDQN, "OffOnDQN": QRDQN}
NAMES = {"DQN": "sb3-contrib QRDQN", "OffOnDQN": "sb3_offon QRDQN"}


def loss_milliseconds(loss_fn, current: th.Tensor, target: th.Tensor, iterations: int) -> float:
    """Milliseconds per forward and backward pass of ``loss_fn``."""
    current = current.clone().requires_grad_(True)
    start = time.perf_counter()
    for _ in range(iterations):
        loss_fn(current, target).backward()
    return 1e3 * (time.perf_counter() - start) / iterations


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="pairs of learn() runs")
    parser.add_argument("--timesteps", type=int, default=10_000, help="timed env steps per run")
    parser.add_argument("--prefill", type=int, default=5_000, help="untimed env steps before, without training")
    parser.add_argument("--switch-every", type=int, default=500, help="env steps between turns")
    parser.add_argument("--loss-rounds", type=int, default=5, help="rounds of the loss-alone measurement")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=str, default=None, help="optional JSON path (a markdown table is written next to it)")
    return parser.parse_args()


if __name__ == "__main__":
    args = parse_args()
    th.set_num_threads(1)
    generator = th.Generator().manual_seed(args.seed)
    current, target = th.randn(32, 200, generator=generator), th.randn(32, 200, generator=generator)
    loss_ms: dict[str, list[float]] = {"sb3-contrib": [], "sb3_offon": []}
    for _ in range(args.loss_rounds):
        loss_ms["sb3-contrib"].append(loss_milliseconds(sb3_contrib_loss, current, target, 100))
        loss_ms["sb3_offon"].append(loss_milliseconds(quantile_huber_loss, current, target, 100))
    loss_median = {name: statistics.median(values) for name, values in loss_ms.items()}
    print(f"loss forward + backward, 32 x 200 x 200: {loss_median} ms")

    hyperparams = dict(ZOO_HYPERPARAMS[MINATAR_BREAKOUT])
    pairs = []
    for repeat in range(args.repeats):
        order = ("DQN", "OffOnDQN") if repeat % 2 == 0 else ("OffOnDQN", "DQN")
        runs = run_pair(
            order,
            MINATAR_BREAKOUT,
            hyperparams,
            args.timesteps,
            args.seed,
            args.switch_every,
            prefill=args.prefill,
            classes=CLASSES,
        )
        pairs.append({"repeat": repeat, "starts": NAMES[order[0]], **{NAMES[role]: run for role, run in runs.items()}})
        print(
            f"  pair {repeat}: "
            + ", ".join(f"{NAMES[role]} {run['steps_per_second']:.0f} steps/s" for role, run in runs.items())
        )
    wall = ratio_summary(*([pair[NAMES[role]]["steps_per_second"] for pair in pairs] for role in ("DQN", "OffOnDQN")))

    git = subprocess.run(["git", "describe", "--always", "--dirty=+dirty"], capture_output=True, text=True).stdout.strip()
    table = "\n".join(
        [
            f"{MINATAR_BREAKOUT}, a gradient step every {hyperparams['train_freq']} env steps, 200 quantiles, one thread, "
            f"{args.timesteps} timed env steps per run after {args.prefill} untimed, {args.repeats} pairs taking turns, "
            f"seed {args.seed}, {os.cpu_count()} CPUs ({platform.processor() or platform.machine()}), sb3_offon {git}, "
            f"sb3-contrib {sb3_contrib.__version__}, torch {th.__version__}",
            "",
            f"Loss forward and backward (32 x 200 against 32 x 200, median of {args.loss_rounds} rounds of 100): "
            f"sb3-contrib's {loss_median['sb3-contrib']:.2f} ms, sb3_offon's {loss_median['sb3_offon']:.2f} ms "
            f"({loss_median['sb3-contrib'] / loss_median['sb3_offon']:.1f}x).",
            "",
            "| pair | starts | sb3-contrib QRDQN steps/s | sb3_offon QRDQN steps/s | ratio |",
            "|---:|---|---:|---:|---:|",
            *(
                f"| {pair['repeat']} | {pair['starts']} | {pair[NAMES['DQN']]['steps_per_second']:.0f} "
                f"| {pair[NAMES['OffOnDQN']]['steps_per_second']:.0f} | {ratio:.2f} |"
                for pair, ratio in zip(pairs, wall["pair_ratios"], strict=True)
            ),
            f"| **median** | | **{wall['dqn_median']:.0f}** | **{wall['offon_median']:.0f}** "
            f"| **{wall['pair_ratio_median']:.2f}** |",
        ]
    )
    print("\n" + table)
    if args.output is not None:
        output = Path(args.output)
        output.parent.mkdir(parents=True, exist_ok=True)
        result = {"args": vars(args), "git": git, "sb3_offon": sb3_offon.__version__, "loss_ms": loss_ms, "pairs": pairs}
        result["hyperparams"], result["wall"] = hyperparams, wall
        output.write_text(json.dumps(result, indent=2, default=lambda value: getattr(value, "__name__", repr(value))) + "\n")
        output.with_suffix(".md").write_text(table + "\n")
        print(f"written: {output} and {output.with_suffix('.md')}")
