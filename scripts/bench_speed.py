"""
Speed benchmark: environment steps per second of OffOnDQN against SB3's DQN at identical hyperparameters.

Both algorithms get the same hyperparameter dict (rl-zoo's tuned DQN settings for the env) and the same seed;
OffOnDQN keeps its constructor defaults for the Off-On parameters (the paper's delta schedules). The runs alternate
in one process (DQN first on even repeats, OffOnDQN first on odd ones) so that slow drift in the machine's load
cancels out. Only ``model.learn()`` is timed; building the model (and its env) is not.

Reported: env steps/s of every run (wall clock, and process CPU time as a cross-check against other load on the
machine), the median of each algorithm, the ratio OffOnDQN / DQN of the medians, and the ratio of each alternating
pair with its min and max. The load average (``os.getloadavg()``) is sampled around every run.

Usage:
    python scripts/bench_speed.py --env CartPole-v1
    python scripts/bench_speed.py --env LunarLander-v3 --timesteps 20000 --repeats 3 --output results/speed/lunarlander.json
"""

import argparse
import gc
import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import stable_baselines3
import torch as th
from stable_baselines3 import DQN

import sb3_offon
from sb3_offon import OffOnDQN
from sb3_offon.offon_dqn.offon_dqn import OFFON_PARAMETERS

# rl-baselines3-zoo's tuned DQN hyperparameters (hyperparams/dqn.yml), minus n_timesteps and the policy name
ZOO_HYPERPARAMS = {
    "CartPole-v1": dict(
        learning_rate=2.3e-3,
        batch_size=64,
        buffer_size=100_000,
        learning_starts=1000,
        gamma=0.99,
        target_update_interval=10,
        train_freq=256,
        gradient_steps=128,
        exploration_fraction=0.16,
        exploration_final_eps=0.04,
        policy_kwargs=dict(net_arch=[256, 256]),
    ),
    "LunarLander-v3": dict(
        learning_rate=6.3e-4,
        batch_size=128,
        buffer_size=50_000,
        learning_starts=0,
        gamma=0.99,
        target_update_interval=250,
        train_freq=4,
        gradient_steps=-1,
        exploration_fraction=0.12,
        exploration_final_eps=0.1,
        policy_kwargs=dict(net_arch=[256, 256]),
    ),
}
ZOO_TIMESTEPS = {"CartPole-v1": 50_000, "LunarLander-v3": 100_000}


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", choices=sorted(ZOO_HYPERPARAMS), default="CartPole-v1", help="environment id")
    parser.add_argument(
        "--timesteps",
        type=int,
        default=20_000,
        help="env steps per timed run (default 20000; the zoo trains 50k on CartPole-v1, 100k on LunarLander-v3)",
    )
    parser.add_argument("--repeats", type=int, default=3, help="number of alternating (DQN, OffOnDQN) pairs")
    parser.add_argument("--seed", type=int, default=0, help="seed of every run (the same for both algorithms)")
    parser.add_argument("--threads", type=int, default=1, help="torch.set_num_threads")
    parser.add_argument(
        "--warmup-timesteps",
        type=int,
        default=2000,
        help="untimed run of each algorithm before the timed ones (first-call costs of torch and numpy); 0: none",
    )
    parser.add_argument("--output", type=str, default=None, help="optional JSON path (a markdown table is written next to it)")
    return parser.parse_args()


def run_once(algo_class: type[DQN], env_id: str, hyperparams: dict, timesteps: int, seed: int) -> dict:
    """Build a model (untimed), then time its learn() call."""
    model = algo_class("MlpPolicy", env_id, seed=seed, verbose=0, device="cpu", **hyperparams)
    # Time train() apart from the rest of learn() (collecting and storing transitions): wrap the bound method
    train_seconds = [0.0]
    untimed_train = model.train

    def timed_train(*args, **kwargs) -> None:
        start = time.perf_counter()
        untimed_train(*args, **kwargs)
        train_seconds[0] += time.perf_counter() - start

    model.train = timed_train  # type: ignore[method-assign]
    gc.collect()
    load_before = os.getloadavg()
    cpu_start, wall_start = time.process_time(), time.perf_counter()
    model.learn(total_timesteps=timesteps)
    wall = time.perf_counter() - wall_start
    cpu = time.process_time() - cpu_start
    load_after = os.getloadavg()
    steps = model.num_timesteps
    episode_lengths = model.env.env_method("get_episode_lengths")[0]  # from SB3's Monitor wrapper
    run = {
        "algo": algo_class.__name__,
        "env_steps": steps,
        "gradient_steps": model._n_updates,
        "learn_seconds": wall,
        "cpu_seconds": cpu,
        "train_seconds": train_seconds[0],
        "collect_seconds": wall - train_seconds[0],
        "episodes": len(episode_lengths),
        "mean_episode_length": float(np.mean(episode_lengths)) if episode_lengths else None,
        "steps_per_second": steps / wall,
        "cpu_steps_per_second": steps / cpu,
        "loadavg_before": load_before,
        "loadavg_after": load_after,
    }
    if isinstance(model, OffOnDQN):
        run["offon_parameters"] = {name: getattr(model, name) for name in OFFON_PARAMETERS}
    model.env.close()
    del model
    return run


def ratio_summary(dqn_values: list[float], offon_values: list[float]) -> dict:
    pair_ratios = [offon / dqn for dqn, offon in zip(dqn_values, offon_values, strict=True)]
    return {
        "dqn_median": statistics.median(dqn_values),
        "offon_median": statistics.median(offon_values),
        "ratio_of_medians": statistics.median(offon_values) / statistics.median(dqn_values),
        "pair_ratios": pair_ratios,
        "pair_ratio_median": statistics.median(pair_ratios),
        "pair_ratio_min": min(pair_ratios),
        "pair_ratio_max": max(pair_ratios),
    }


def markdown_table(result: dict) -> str:
    wall, cpu = result["summary"]["wall"], result["summary"]["cpu"]
    lines = [
        f"{result['env']}, {result['timesteps']} env steps per run, {result['repeats']} alternating pairs, "
        f"seed {result['seed']}, {result['threads']} torch thread(s), load average "
        f"{result['loadavg_start'][0]:.2f} at start / {result['loadavg_end'][0]:.2f} at end ({result['cpu_count']} CPUs), "
        f"sb3_offon {result['git']}, SB3 {result['versions']['stable_baselines3']}, torch {result['versions']['torch']}",
        "",
        "| pair | order | DQN steps/s | OffOnDQN steps/s | ratio | DQN CPU steps/s | OffOnDQN CPU steps/s | CPU ratio |",
        "|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for pair in result["pairs"]:
        dqn, offon = pair["DQN"], pair["OffOnDQN"]
        lines.append(
            f"| {pair['repeat']} | {pair['order']} | {dqn['steps_per_second']:.0f} | {offon['steps_per_second']:.0f} "
            f"| {offon['steps_per_second'] / dqn['steps_per_second']:.3f} | {dqn['cpu_steps_per_second']:.0f} "
            f"| {offon['cpu_steps_per_second']:.0f} | {offon['cpu_steps_per_second'] / dqn['cpu_steps_per_second']:.3f} |"
        )
    lines.append(
        f"| **median** | | **{wall['dqn_median']:.0f}** | **{wall['offon_median']:.0f}** | **{wall['ratio_of_medians']:.3f}** "
        f"| **{cpu['dqn_median']:.0f}** | **{cpu['offon_median']:.0f}** | **{cpu['ratio_of_medians']:.3f}** |"
    )
    lines += [
        "",
        f"Pair ratios (wall): median {wall['pair_ratio_median']:.3f}, min {wall['pair_ratio_min']:.3f}, "
        f"max {wall['pair_ratio_max']:.3f}; (CPU): median {cpu['pair_ratio_median']:.3f}, min {cpu['pair_ratio_min']:.3f}, "
        f"max {cpu['pair_ratio_max']:.3f}.",
        "",
        "Where the time of learn() went: train() (sampling, targets, gradient steps) and the rest (acting, env steps, "
        "storing transitions), in microseconds per env step:",
        "",
        "| pair | algorithm | learn | train | rest | episodes | mean episode length |",
        "|---:|---|---:|---:|---:|---:|---:|",
    ]
    for pair in result["pairs"]:
        for algo in ("DQN", "OffOnDQN"):
            run = pair[algo]
            per_step = 1e6 / run["env_steps"]
            lines.append(
                f"| {pair['repeat']} | {algo} | {run['learn_seconds'] * per_step:.0f} | {run['train_seconds'] * per_step:.0f} "
                f"| {run['collect_seconds'] * per_step:.0f} | {run['episodes']} | {run['mean_episode_length']:.1f} |"
            )
    return "\n".join(lines)


if __name__ == "__main__":
    args = parse_args()
    th.set_num_threads(args.threads)
    hyperparams = ZOO_HYPERPARAMS[args.env]  # one dict, passed as it is to both algorithms
    gym.make(args.env).close()  # fail early if the env (Box2D for LunarLander) is missing

    result = {
        "env": args.env,
        "timesteps": args.timesteps,
        "zoo_timesteps": ZOO_TIMESTEPS[args.env],
        "repeats": args.repeats,
        "seed": args.seed,
        "threads": args.threads,
        "hyperparams": hyperparams,
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "processor": platform.processor(),
        "python": platform.python_version(),
        "versions": {
            "sb3_offon": sb3_offon.__version__,
            "stable_baselines3": stable_baselines3.__version__,
            "torch": th.__version__,
            "gymnasium": gym.__version__,
            "numpy": np.__version__,
        },
        "git": subprocess.run(  # the commit measured, "+dirty" when the working tree has changes
            ["git", "describe", "--always", "--dirty=+dirty"], capture_output=True, text=True, cwd=Path(__file__).parent
        ).stdout.strip(),
        "loadavg_start": os.getloadavg(),
        "pairs": [],
    }
    print(f"{args.env}: {args.repeats} pairs of {args.timesteps} env steps, seed {args.seed}, {args.threads} thread(s)")
    print(f"hyperparams: {hyperparams}")
    print(f"load average at start: {result['loadavg_start']} ({result['cpu_count']} CPUs)")

    if args.warmup_timesteps > 0:
        for algo_class in (DQN, OffOnDQN):
            run_once(algo_class, args.env, hyperparams, args.warmup_timesteps, args.seed)
        print(f"warm-up done ({args.warmup_timesteps} steps of each, untimed)")

    for repeat in range(args.repeats):
        order = (DQN, OffOnDQN) if repeat % 2 == 0 else (OffOnDQN, DQN)
        pair = {"repeat": repeat, "order": " then ".join(algo.__name__ for algo in order)}
        for algo_class in order:
            run = run_once(algo_class, args.env, hyperparams, args.timesteps, args.seed)
            pair[run["algo"]] = run
            print(
                f"  pair {repeat} {run['algo']:>8}: {run['steps_per_second']:7.1f} steps/s "
                f"({run['env_steps']} steps, {run['gradient_steps']} gradient steps, {run['learn_seconds']:.1f} s wall, "
                f"{run['cpu_seconds']:.1f} s CPU, load {run['loadavg_before'][0]:.2f} -> {run['loadavg_after'][0]:.2f})"
            )
        result["pairs"].append(pair)
    result["loadavg_end"] = os.getloadavg()
    result["offon_parameters"] = result["pairs"][0]["OffOnDQN"]["offon_parameters"]

    result["summary"] = {
        key: ratio_summary(
            [pair["DQN"][metric] for pair in result["pairs"]],
            [pair["OffOnDQN"][metric] for pair in result["pairs"]],
        )
        for key, metric in (("wall", "steps_per_second"), ("cpu", "cpu_steps_per_second"))
    }
    # Median microseconds per env step spent in train() and in the rest of learn()
    result["summary"]["us_per_env_step"] = {
        algo: {
            part: statistics.median(1e6 * pair[algo][f"{part}_seconds"] / pair[algo]["env_steps"] for pair in result["pairs"])
            for part in ("learn", "train", "collect")
        }
        for algo in ("DQN", "OffOnDQN")
    }
    wall = result["summary"]["wall"]
    print(
        f"\nOffOnDQN / DQN (ratio of median steps/s): {wall['ratio_of_medians']:.3f} "
        f"(pairs: median {wall['pair_ratio_median']:.3f}, min {wall['pair_ratio_min']:.3f}, "
        f"max {wall['pair_ratio_max']:.3f})\n"
    )
    table = markdown_table(result)
    print(table)

    if args.output is not None:
        output = Path(args.output)
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(json.dumps(result, indent=2) + "\n")
        output.with_suffix(".md").write_text(table + "\n")
        print(f"\nwritten: {output} and {output.with_suffix('.md')}")
