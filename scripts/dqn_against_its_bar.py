"""
Would DQN pass the search's point rule of rounds 1-4? Every task's five-seed mean final return within 2% of the range
of DQN's mean on seeds 0-4 (the bar), asked of DQN's own runs on other seeds: the first head-to-head's seeds 10-14 and
15-19 (the same zoo settings and budgets), and of five runs drawn at random from DQN's fifteen.

Usage::

    python scripts/dqn_against_its_bar.py   # the Markdown table of results/search/README.md's round-4 outcome
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import search

parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
parser.add_argument("--headtohead-root", type=Path, default=Path("results/raw/headtohead/dqn"))
parser.add_argument("--draws", type=int, default=20_000)
args = parser.parse_args()

rng = np.random.default_rng(0)
header = ["Task", "DQN, seeds 0-4 (the bar's reference)", "bar", "DQN, seeds 10-14", "DQN, seeds 15-19"]
print("| " + " | ".join([*header, "five of DQN's 15 runs drawn at random pass"]) + " |")
print("|---|---:|---:|---:|---:|---:|")
all_pass = 1.0
for env in search.BENCHMARK_ENVS:
    reference = search.collect(search.BY_NAME["dqn"], env)[:, 0]
    bar = search.bar(env, reference.mean())
    fresh = np.array([search.run_scores(args.headtohead_root / f"{env}_{seed}")[0] for seed in range(10, 20)])
    # Five runs drawn with replacement from all fifteen, as if DQN were a candidate judged on five new seeds
    draws = rng.choice(np.concatenate([reference, fresh]), size=(args.draws, 5)).mean(axis=1)
    share = float((draws >= bar).mean())
    all_pass *= share
    cells = [f"{reference.mean():.1f}", f"{bar:.1f}", f"{fresh[:5].mean():.1f}", f"{fresh[5:].mean():.1f}", f"{share:.0%}"]
    print(f"| {env} | " + " | ".join(cells) + " |")
print(f"\nAll four bars passed by five random runs of DQN's: about {all_pass:.2f} of the draws (product over the tasks).")
