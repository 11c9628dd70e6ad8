"""
What the search runs: the tasks, the tuning seeds and every candidate of every round, each with
the settings it overrides in the bundled tuned hyperparameters. ``scripts/search.py`` runs and judges them; why each
round has the candidates it has, and the criterion that judges it, are in its docstring and in
``results/search/README.md``, both written before the round's runs.
"""

import sys
from dataclasses import dataclass, field
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchmark

TUNING_SEEDS = [0, 1, 2, 3, 4]
BENCHMARK_ENVS = ["CartPole-v1", "MountainCar-v0", "LunarLander-v3", "Acrobot-v1"]
STOCHASTIC_ENV = "FrozenLake-v1"
OFFON_ENVS = [*BENCHMARK_ENVS, STOCHASTIC_ENV]


@dataclass
class Candidate:
    name: str
    algo: str
    hyperparams: list[str] = field(default_factory=list)
    envs: list[str] = field(default_factory=lambda: list(OFFON_ENVS))
    # Runs of the tuned grid made with exactly these settings (no overrides): read from there on these envs
    reuse_tuned: bool = False
    description: str = ""
    # Per task, more overrides (after ``hyperparams``)
    per_env: dict[str, list[str]] = field(default_factory=dict)
    # 1: the search as first stated; 2: the round added after the head-to-head; 3 to 5: the lambda-return stages
    # (each round its own criterion, scripts/search.py's docstring)
    round: int = 1
    # Per task, the seeds it is judged on where they are not the tuning seeds 0-4
    seeds: dict[str, list[int]] = field(default_factory=dict)
    # The folder name of its runs where it is not ``algo``: the paper's configuration ran as offon_dqn, its name until
    # 2026-11-27 (today offon_dqn is OffOnDQN's defaults and offon_paper the paper's)
    run_name: str = ""

    @property
    def folder_name(self) -> str:
        return self.run_name or self.algo

    def seeds_on(self, env: str) -> list[int]:
        return self.seeds.get(env, TUNING_SEEDS)


MAX = "mc_mixing:'max'"
# Round 2: the bound from observed returns only, wherever the return is known
OBSERVED_BOUND = [MAX, "mc_truncation:'drop'", "mc_initial_prob:1.0", "mc_final_prob:1.0"]
CANDIDATES = [
    Candidate("dqn", "dqn", reuse_tuned=True, description="SB3's DQN, the zoo's settings (the reference)"),
    Candidate(
        "paper",
        "offon_paper",
        reuse_tuned=True,
        description="the paper: one target drawn, delta1 and delta2 0.99 -> 0.01",
        run_name="offon_dqn",
    ),
    Candidate("mc_sample", "dqn_mc", reuse_tuned=True, description="DQN with MC: delta1 0.99 -> 0.01, no Sarsa"),
    Candidate(
        "max_paper", "offon_paper", [MAX], description="lower bound max(G, y_TD), the paper's schedules", run_name="offon_dqn"
    ),
    Candidate("max_qlearning", "dqn_mc", [MAX], description="lower bound, delta1 0.99 -> 0.01, no Sarsa"),
    Candidate(
        "max_always",
        "dqn_mc",
        [MAX, "mc_initial_prob:1.0", "mc_final_prob:1.0"],
        description="lower bound wherever G is known (MCAC), no Sarsa",
    ),
    *[
        Candidate(f"nstep{n}", "dqn_nstep", [f"n_steps:{n}"], envs=list(BENCHMARK_ENVS), description=f"SB3's DQN, n_steps={n}")
        for n in (3, 5, 10)
    ],
    Candidate(
        "max_drop",
        "dqn_mc",
        OBSERVED_BOUND,
        round=2,
        description="lower bound wherever an observed return is known (time-limit cuts' returns dropped), no Sarsa",
    ),
    Candidate(
        "max_drop_nstep10",
        "dqn_mc",
        [*OBSERVED_BOUND, "n_steps:10"],
        round=2,
        description="the same on 10-step TD targets",
    ),
]


def exploration_fractions(algo: str = "offon_lambda") -> dict[str, float]:
    """Per task, the exploration fraction of the bundled tuned settings (the zoo's), read from ``hyperparams/``."""
    entries = yaml.safe_load(benchmark.config_file("tuned", algo).read_text())
    return {env: float(entries[env]["exploration_fraction"]) for env in OFFON_ENVS}


def lambda_schedule(initial: float, final: float, fraction: float = 1.0) -> list[str]:
    """
    delta1 read as lambda: from ``initial`` to ``final`` over ``fraction`` of the training, then ``final`` (constant
    where they are equal).
    """
    return [f"mc_initial_prob:{initial}", f"mc_final_prob:{final}", f"mc_fraction:{fraction}"]


def trace_cuts(initial: float, final: float) -> list[str]:
    """delta2, the trace-cut weight: 1 is Watkins's Q(lambda), 0 Peng's."""
    return [f"qlearning_initial_prob:{initial}", f"qlearning_final_prob:{final}"]


# Round 3: the lambda-returns; offon_lambda's YAML gives every other setting
WATKINS, PENG = trace_cuts(1.0, 1.0), trace_cuts(0.0, 0.0)
CANDIDATES += [
    *[
        Candidate(
            f"lambda{round(lam * 100)}_watkins",
            "offon_lambda",
            [*lambda_schedule(lam, lam), *WATKINS],
            round=3,
            description=f"lambda {lam}, Watkins's cuts (delta2 = 1)",
        )
        for lam in (0.8, 0.9, 0.95)
    ],
    Candidate(
        "lambda90_peng",
        "offon_lambda",
        [*lambda_schedule(0.9, 0.9), *PENG],
        round=3,
        description="lambda 0.9, Peng's (no cuts, delta2 = 0)",
    ),
    Candidate(
        "lambda90_peng_to_watkins",
        "offon_lambda",
        [*lambda_schedule(0.9, 0.9), *trace_cuts(0.0, 1.0)],
        per_env={env: [f"qlearning_fraction:{fraction}"] for env, fraction in exploration_fractions().items()},
        round=3,
        description="lambda 0.9, delta2 0 -> 1 over the exploration period (Peng to Watkins as epsilon decays)",
    ),
    Candidate(
        "lambda_paper_watkins",
        "offon_lambda",
        [*lambda_schedule(0.99, 0.01), *WATKINS],
        round=3,
        description="lambda 0.99 -> 0.01 over training (the paper's delta1), Watkins's cuts",
    ),
]
# Round 4: lambda-returns that end nearer one-step Q-learning; FrozenLake judged on ten seeds (module docstring)
ROUND4_SEEDS = {STOCHASTIC_ENV: list(range(10))}
CANDIDATES += [
    Candidate(
        "lambda_paper_peng",
        "offon_lambda",
        [*lambda_schedule(0.99, 0.01), *PENG],
        round=4,
        seeds=ROUND4_SEEDS,
        description="lambda 0.99 -> 0.01 over training (the paper's delta1), Peng's (no cuts)",
    ),
    Candidate(
        "lambda90_peng_half",
        "offon_lambda",
        [*lambda_schedule(0.9, 0.0, fraction=0.5), *PENG],
        round=4,
        seeds=ROUND4_SEEDS,
        description="lambda 0.9 -> 0 over the first half of training, Peng's (no cuts); one-step Q-learning after",
    ),
    Candidate(
        "lambda70_watkins",
        "offon_lambda",
        [*lambda_schedule(0.7, 0.7), *WATKINS],
        round=4,
        seeds=ROUND4_SEEDS,
        description="lambda 0.7, Watkins's cuts (delta2 = 1)",
    ),
]

# Round 5: rounds 3 and 4's fastest lambda-return settings and the Watkins setting that missed one bar, judged afresh on
# tuning seeds of their own (30-34, never used before; 10-19 were the first head-to-head's, 20-29 are reserved) by a
# screen that DQN's own runs pass (scripts/search.py's docstring); DQN's reference made on the same seeds, in a folder of
# its own so that the tuned grid keeps its seeds
ROUND5_SEEDS = {env: [30, 31, 32, 33, 34] for env in OFFON_ENVS}
ROUND5_REFERENCE = "dqn_r5"
CANDIDATES += [
    Candidate(
        ROUND5_REFERENCE, "dqn", round=5, seeds=ROUND5_SEEDS, description="SB3's DQN, the zoo's settings (the reference)"
    ),
    Candidate(
        "lambda90_peng_r5",
        "offon_lambda",
        [*lambda_schedule(0.9, 0.9), *PENG],
        round=5,
        seeds=ROUND5_SEEDS,
        description="lambda 0.9, Peng's (no cuts): round 3's lambda90_peng",
    ),
    Candidate(
        "lambda_paper_peng_r5",
        "offon_lambda",
        [*lambda_schedule(0.99, 0.01), *PENG],
        round=5,
        seeds=ROUND5_SEEDS,
        description="lambda 0.99 -> 0.01 over training, Peng's (no cuts): round 4's lambda_paper_peng",
    ),
    Candidate(
        "lambda80_watkins_r5",
        "offon_lambda",
        [*lambda_schedule(0.8, 0.8), *WATKINS],
        round=5,
        seeds=ROUND5_SEEDS,
        description="lambda 0.8, Watkins's cuts: round 3's lambda80_watkins",
    ),
]
BY_NAME = {candidate.name: candidate for candidate in CANDIDATES}
OFFON_CANDIDATES = [candidate.name for candidate in CANDIDATES if candidate.algo != "dqn_nstep" and candidate.round == 1]
ROUND2_CANDIDATES = [candidate.name for candidate in CANDIDATES if candidate.round == 2]
ROUND2_REFERENCE = "nstep10"
ROUND3_CANDIDATES = [candidate.name for candidate in CANDIDATES if candidate.round == 3]
ROUND4_CANDIDATES = [candidate.name for candidate in CANDIDATES if candidate.round == 4]
ROUND5_CANDIDATES = [candidate.name for candidate in CANDIDATES if candidate.round == 5 and candidate.algo != "dqn"]
