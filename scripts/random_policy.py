"""
The return of a uniformly random policy on Gymnasium envs: the low end of a study's score normalisation.

Each env plays ``--episodes`` episodes, episode i reset with seed ``--seed`` + i and the actions drawn from the action
space seeded with ``--seed``; the mean return comes with its 95% percentile bootstrap interval over the episodes.
The results are printed as a table and, with ``--out``, written as JSON (env id -> mean, low, high, episodes, mean length).

Usage::

    python scripts/random_policy.py --envs MinAtar/Asterix-v0 MinAtar/Breakout-v0 --episodes 100 --out random.json
"""

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
from scipy import stats

import sb3_offon  # noqa: F401  (registers the package's env ids)


def play(env_id: str, episodes: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The returns and lengths of ``episodes`` episodes of uniformly random actions."""
    env = gym.make(env_id)
    env.action_space.seed(seed)
    returns, lengths = np.zeros(episodes), np.zeros(episodes, dtype=int)
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        done = False
        while not done:
            _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            returns[episode] += float(reward)
            lengths[episode] += 1
            done = terminated or truncated
    env.close()
    return returns, lengths


def summary(returns: np.ndarray, lengths: np.ndarray) -> dict[str, float]:
    """Mean return and its 95% percentile bootstrap interval (seeded), episodes, mean length."""
    if np.ptp(returns) == 0:  # every episode scored the same: nothing to resample
        low = high = float(returns[0])
    else:
        interval = stats.bootstrap((returns,), np.mean, n_resamples=10_000, method="percentile", rng=0).confidence_interval
        low, high = float(interval.low), float(interval.high)
    mean_length = float(lengths.mean())
    return {"mean": float(returns.mean()), "low": low, "high": high, "episodes": len(returns), "mean_length": mean_length}


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[1], formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--envs", nargs="+", required=True, help="env ids")
    parser.add_argument("--episodes", type=int, default=100, help="episodes per env (default: 100)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode and of the actions (default: 0)")
    parser.add_argument("--out", type=Path, default=None, help="JSON file to write")
    args = parser.parse_args(argv)
    results = {env_id: summary(*play(env_id, args.episodes, args.seed)) for env_id in args.envs}
    print("| env | random policy's mean return [95% CI] | episodes | mean length |\n|---|---|---|---|")
    for env_id, row in results.items():
        interval = f"{row['mean']:.3f} [{row['low']:.3f}, {row['high']:.3f}]"
        print(f"| {env_id} | {interval} | {row['episodes']} | {row['mean_length']:.1f} |")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"seed": args.seed, "results": results}, indent=2) + "\n")
    return results


if __name__ == "__main__":
    main()
