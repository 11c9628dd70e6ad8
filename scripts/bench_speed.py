"""
Speed benchmark: environment steps per second of OffOnDQN against SB3's DQN at identical hyperparameters (or, with
``--candidate offon_qrdqn``, of OffOnQRDQN against this package's QR-DQN).

Both algorithms get the same hyperparameter dict (rl-zoo's tuned DQN settings for the env; the MinAtar paper's for
MinAtar/Breakout-v0) and the same seed. OffOnDQN's targets (``--mode``): ``defaults``, its constructor's (lambda-returns,
lambda 0.9, Peng's Q(lambda)); ``paper``, the paper's coin flips (``PAPER_TARGETS``); ``lambda``, ``offon_lambda``'s
(lambda 0.9, Watkins's cuts); ``double_q``, the defaults with double Q-learning. The baseline (``--baseline``, the "DQN"
columns): SB3's DQN, SB3's DQN with ``n_steps=10`` (``dqn_nstep``), or OffOnDQN with its defaults (``offon_defaults``,
to measure what an option of OffOnDQN costs). ``--candidate offon_qrdqn`` measures the QR-DQN family instead: OffOnQRDQN
(``--mode defaults``, its constructor's; ``projected``, the projected recursion; ``no_cache``, no cache and lambda 0.67;
``double_q``; ``median``, ``lambda_choice="median"``, which OffOnDQN takes too) against ``sb3_offon.qrdqn.QRDQN``
(``--baseline qrdqn``, its default then), both with QR-DQN's default 200 quantiles.
``--baseline qrdqn_nstep`` is that QR-DQN with ``n_steps=3`` (MinAtar's n): against OffOnDQN, it measures what the
quantile critic costs next to the defaults; against OffOnQRDQN, what lambda-returns cost next to n-step returns.
``--hyperparams key:value ...`` adds the candidate's own arguments on top of the mode's, parsed as the training command
line parses them (a study file's ``hyperparams`` as they are), so that any configuration a study runs can be priced.
Tables and JSON keep the roles' names ("DQN" the baseline, "OffOnDQN" the candidate) and say which classes and
arguments they are.

The two runs of a pair take turns in one process: each learn() runs in a thread of its own, and they hand a baton
to each other every ``--switch-every`` env steps (from a callback), so only one of them computes at any time. A
machine whose speed drifts (a shared VM's can change by half within minutes) then slows both runs alike, where two
runs one after the other would each see a different machine. Each run is timed over the intervals in which it held
the baton (wall clock), and by its thread's CPU time as a cross-check; building the models is not timed. The pairs
alternate which algorithm starts.

Reported: env steps/s of every run (wall and CPU), the median of each algorithm, the ratio OffOnDQN / DQN of the
medians, and the ratio of each pair with its min and max; the time spent in train() and in the rest of learn().
The load average (``os.getloadavg()``) is sampled around every pair.

Usage:
    python scripts/bench_speed.py --env CartPole-v1
    python scripts/bench_speed.py --env LunarLander-v3 --timesteps 20000 --repeats 3 --output results/speed/lunarlander.json
    python scripts/bench_speed.py --env CartPole-v1 --device cuda --output results/speed/cartpole_cuda.json
    python scripts/bench_speed.py --env AtariShaped --device cuda --timesteps 5000 --output results/speed/atari_cuda.json
    python scripts/bench_speed.py --env LunarLander-v3 --mode lambda --baseline dqn_nstep --repeats 5
    python scripts/bench_speed.py --env MinAtar/Breakout-v0 --mode defaults --train-freq 1 --timesteps 15000 --prefill 5000
    python scripts/bench_speed.py --env LunarLander-v3 --mode double_q --baseline offon_defaults
    python scripts/bench_speed.py --env MinAtar/Breakout-v0 --candidate offon_qrdqn --prefill 10000 --flush-denormals
    python scripts/bench_speed.py --env LunarLander-v3 --mode per --baseline offon_defaults
    python scripts/bench_speed.py --env MinAtar/Breakout-v0 --baseline qrdqn_nstep --prefill 10000 --flush-denormals
    python scripts/bench_speed.py --env MinAtar/Breakout-v0 --candidate offon_qrdqn --baseline qrdqn_nstep \
        --hyperparams mc_initial_prob:0.670 mc_final_prob:0.670 --train-freq 4 --prefill 10000 --flush-denormals

``--env AtariShaped100k`` (DER's network) and ``AtariShaped100kNature`` (SB3's NatureCNN) run that task with the
Atari 100k settings (an update per env step; without ``optimize_memory_usage``, which SB3's n-step buffer refuses).
``--env AtariShaped`` is an Atari-shaped task made up on the spot (4 stacked 84x84 uint8 frames, episodes of 200 steps
that end by termination, CnnPolicy, the zoo's Atari DQN settings with a smaller buffer), so that CNNs can be measured,
on a GPU too, without Atari ROMs. On ``--device cuda`` every timed interval ends with ``torch.cuda.synchronize()``, so
that the device's queued work is counted in the run that queued it.
"""

import argparse
import gc
import json
import os
import platform
import random
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import stable_baselines3
import torch as th
from stable_baselines3 import DQN
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.envs import FakeImageEnv

import sb3_offon
from sb3_offon import PAPER_TARGETS, DataEfficientCNN, MinAtarCNN, OffOnDQN, OffOnQRDQN, PrioritizedOffOnReplayBuffer
from sb3_offon.cli_args import TolerantStoreDict
from sb3_offon.offon_dqn.offon_dqn import OFFON_PARAMETERS
from sb3_offon.qrdqn import QRDQN

# speed_report.py sits next to this script: importable however it is started (as a script, or loaded from its path)
sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed_report import markdown_table, ratio_summary

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
# An Atari-shaped task without Atari: SB3's FakeImageEnv with 4 stacked 84x84 uint8 frames (channel first, as the
# zoo's AtariWrapper and frame stack give them to CnnPolicy), random frames and rewards, nothing downloaded. The zoo's
# Atari DQN settings, except a smaller buffer and an earlier start of learning, so that a short run trains at all.
ATARI_SHAPED = "AtariShaped"
ZOO_HYPERPARAMS[ATARI_SHAPED] = dict(
    learning_rate=1e-4,
    batch_size=32,
    buffer_size=10_000,
    learning_starts=1000,
    target_update_interval=1000,
    train_freq=4,
    gradient_steps=1,
    exploration_fraction=0.1,
    exploration_final_eps=0.01,
)
# The Atari 100k settings (sb3_offon/hyperparams/atari100k/) on the Atari-shaped task: an update per env step, DER's
# network (AtariShaped100k) or SB3's NatureCNN (AtariShaped100kNature). Without optimize_memory_usage, which SB3's
# n-step buffer refuses, so that both runs of a pair store their transitions alike (what it saves is memory, not time)
ATARI_100K_SHAPED, ATARI_100K_SHAPED_NATURE = "AtariShaped100k", "AtariShaped100kNature"
ATARI_100K_SETTINGS = dict(
    learning_rate=1e-4,
    batch_size=32,
    buffer_size=100_000,
    learning_starts=1600,
    target_update_interval=2000,
    train_freq=1,
    gradient_steps=1,
    gamma=0.99,
    exploration_fraction=0.02,
    exploration_final_eps=0.01,
)
ZOO_HYPERPARAMS[ATARI_100K_SHAPED] = dict(
    ATARI_100K_SETTINGS,
    policy_kwargs=dict(features_extractor_class=DataEfficientCNN, net_arch=[], optimizer_kwargs=dict(eps=1.5e-4)),
)
ZOO_HYPERPARAMS[ATARI_100K_SHAPED_NATURE] = dict(ATARI_100K_SETTINGS, policy_kwargs=dict(optimizer_kwargs=dict(eps=1.5e-4)))
# The MinAtar paper's DQN settings, as in the bundled YAML files (sb3_offon/hyperparams/dqn.yml), with its network
MINATAR_BREAKOUT = "MinAtar/Breakout-v0"
ZOO_HYPERPARAMS[MINATAR_BREAKOUT] = dict(
    learning_rate=2.5e-4,
    batch_size=32,
    buffer_size=100_000,
    learning_starts=5000,
    gamma=0.99,
    target_update_interval=1000,
    train_freq=4,
    gradient_steps=1,
    exploration_fraction=0.1,
    exploration_final_eps=0.1,
    policy_kwargs=dict(
        features_extractor_class=MinAtarCNN,
        net_arch=[],
        optimizer_class=th.optim.RMSprop,
        optimizer_kwargs=dict(alpha=0.95, eps=0.01, centered=True),
    ),
)
# --mode: OffOnDQN's targets. "paper" is the paper's coin flips (the constructor's defaults until the lambda-returns
# became them: results written before then with mode "paper" measured those same targets)
LAMBDA_TARGETS = dict(
    mc_mixing="lambda", mc_initial_prob=0.9, mc_final_prob=0.9, qlearning_initial_prob=1.0, qlearning_final_prob=1.0
)
MODES = {
    "defaults": {},
    "paper": dict(PAPER_TARGETS),
    "lambda": LAMBDA_TARGETS,
    "double_q": dict(double_q=True),
    "projected": dict(lambda_form="projected"),  # OffOnQRDQN only
    # OffOnQRDQN only: no cache, a horizon drawn per sample, lambda at the contraction of a 3-step return (gamma 0.99)
    "no_cache": dict(lambda_cache=False, mc_initial_prob=0.67, mc_final_prob=0.67),
    "per": dict(replay_buffer_class=PrioritizedOffOnReplayBuffer),  # prioritised replay, Rainbow's alpha 0.5, beta 0.4
    "median": dict(lambda_choice="median"),  # a lambda per transition and refresh (sb3_offon/common/lambda_choice.py)
}
# --candidate: the class of the "OffOnDQN" runs, and the baseline it is measured against unless --baseline says
CANDIDATES: dict[str, tuple[type, str]] = {"offon_dqn": (OffOnDQN, "dqn"), "offon_qrdqn": (OffOnQRDQN, "qrdqn")}
# --baseline: the class and arguments of the "DQN" runs. dqn_nstep: SB3's n-step DQN as in the classic-control
# head-to-heads (hyperparams/dqn_nstep.yml uses n = 10 on those tasks)
BASELINES: dict[str, tuple[type[DQN], dict]] = {
    "dqn": (DQN, {}),
    "dqn_nstep": (DQN, dict(n_steps=10)),
    "offon_defaults": (OffOnDQN, {}),
    "qrdqn": (QRDQN, {}),
    "qrdqn_nstep": (QRDQN, dict(n_steps=3)),  # n-step QR-DQN with MinAtar's n (hyperparams/qrdqn_nstep.yml)
    "offon_qrdqn_defaults": (OffOnQRDQN, {}),
}
ZOO_TIMESTEPS = {"CartPole-v1": 50_000, "LunarLander-v3": 100_000, ATARI_SHAPED: 10_000_000, MINATAR_BREAKOUT: 1_000_000}
POLICIES = {"CartPole-v1": "MlpPolicy", "LunarLander-v3": "MlpPolicy", ATARI_SHAPED: "CnnPolicy"}
POLICIES[MINATAR_BREAKOUT] = "CnnPolicy"
for _name in (ATARI_100K_SHAPED, ATARI_100K_SHAPED_NATURE):
    ZOO_TIMESTEPS[_name], POLICIES[_name] = 100_000, "CnnPolicy"
# The two runs of a pair by role: "DQN" is the baseline (whatever --baseline names), "OffOnDQN" the candidate
ROLES = ("DQN", "OffOnDQN")


class AtariShapedEnv(FakeImageEnv):
    """
    Random 4x84x84 uint8 frames, 4 actions, zero rewards; episodes of ``ep_length`` steps that end by termination.

    SB3's FakeImageEnv ends every 10 steps by truncation, where OffOnDQN runs the target network on the final frames to
    bootstrap the return (one CNN forward pass per episode). Atari episodes under the zoo's AtariWrapper end by
    termination (a lost life counts as one) after hundreds of steps: this env is shaped like that.
    """

    def __init__(self, ep_length: int = 200):
        super().__init__(action_dim=4, screen_height=84, screen_width=84, n_channels=4, discrete=True, channel_first=True)
        self.ep_length = ep_length

    def step(self, action: np.ndarray | int) -> tuple:
        observation, reward, _, truncated, info = super().step(action)
        return observation, reward, truncated, False, info


def make_env(env_id: str) -> gym.Env:
    if env_id in (ATARI_SHAPED, ATARI_100K_SHAPED, ATARI_100K_SHAPED_NATURE):
        return AtariShapedEnv()
    return gym.make(env_id)  # MinAtar's ids are registered by ``import sb3_offon``


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", choices=sorted(ZOO_HYPERPARAMS), default="CartPole-v1", help="environment id")
    parser.add_argument(
        "--timesteps",
        type=int,
        default=20_000,
        help="env steps per timed run (default 20000; the zoo trains 50k on CartPole-v1, 100k on LunarLander-v3)",
    )
    parser.add_argument("--repeats", type=int, default=3, help="number of (DQN, OffOnDQN) pairs")
    parser.add_argument(
        "--switch-every", type=int, default=500, help="env steps a run of a pair takes before handing over to the other"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of every run (the same for both algorithms)")
    parser.add_argument("--threads", type=int, default=1, help="torch.set_num_threads")
    parser.add_argument(
        "--device", choices=["cpu", "cuda"], default="cpu", help="where the networks train (the env steps on the CPU)"
    )
    parser.add_argument(
        "--warmup-timesteps",
        type=int,
        default=2000,
        help="untimed run of each algorithm before the timed ones (first-call costs of torch and numpy); 0: none",
    )
    parser.add_argument(
        "--prefill",
        type=int,
        default=0,
        help="env steps each model collects, untimed and without training, before its timed run (a fuller buffer: "
        "the lambda mode's refresh reaches its steady size only once the buffer holds more than a refresh computes)",
    )
    parser.add_argument("--mode", choices=sorted(MODES), default="defaults", help="OffOnDQN's targets (default: defaults)")
    parser.add_argument(
        "--hyperparams",
        nargs="+",
        action=TolerantStoreDict,  # parsed as the command line parses them (python -m sb3_offon.train --hyperparams)
        default={},
        metavar="KEY:VALUE",
        help="the candidate's own arguments on top of --mode's, as a study file or the command line gives them "
        "(mc_initial_prob:0.670 n_steps:3 lambda_form:projected); not the settings both runs share (--train-freq)",
    )
    parser.add_argument(
        "--candidate",
        choices=sorted(CANDIDATES),
        default="offon_dqn",
        help="the algorithm measured: OffOnDQN (default) or OffOnQRDQN",
    )
    parser.add_argument(
        "--baseline",
        choices=sorted(BASELINES),
        default=None,
        help="SB3's DQN, its n-step DQN (n = 10), OffOnDQN with its defaults, QR-DQN, or n-step QR-DQN (n = 3) "
        "(default: dqn for OffOnDQN, qrdqn for OffOnQRDQN)",
    )
    parser.add_argument(
        "--flush-denormals",
        action="store_true",
        help="flush denormal floats to zero on the CPU, as the command line does by default (python -m sb3_offon.train)",
    )
    parser.add_argument(
        "--train-freq", type=int, default=None, help="env steps between gradient steps, for both runs (default: the settings')"
    )
    parser.add_argument("--output", type=str, default=None, help="optional JSON path (a markdown table is written next to it)")
    return parser.parse_args(argv)


def candidate_arguments(mode: str, hyperparams: dict, shared: dict) -> dict:
    """
    The candidate's own arguments: its mode's, then ``--hyperparams``. A setting both runs share (``train_freq``,
    ``batch_size``, ...) is refused: changed for the candidate alone, the two runs of a pair would not be the same job.
    """
    overlap = sorted(set(hyperparams) & set(shared))
    if overlap:
        raise SystemExit(
            f"--hyperparams: {', '.join(overlap)} is a setting both runs share (--train-freq for train_freq); "
            "changed for the candidate alone, a pair would time different jobs"
        )
    return {**MODES[mode], **hyperparams}


class Baton:
    """Two threads take turns: one holds the baton and runs, the other waits for it."""

    def __init__(self, first: str, second: str):
        self.condition = threading.Condition()
        self.names = (first, second)
        self.holder = first
        self.finished: set[str] = set()

    def wait_turn(self, name: str) -> None:
        with self.condition:
            self.condition.wait_for(lambda: self.holder == name)

    def hand_over(self, name: str, finished: bool = False) -> None:
        with self.condition:
            if finished:
                self.finished.add(name)
            other = self.names[1] if name == self.names[0] else self.names[0]
            if other not in self.finished:
                self.holder = other
                self.condition.notify_all()


def global_rng_states() -> tuple:
    return random.getstate(), np.random.get_state(), th.get_rng_state()


def set_global_rng_states(states: tuple) -> None:
    random.setstate(states[0])
    np.random.set_state(states[1])
    th.set_rng_state(states[2])


class TakeTurns(BaseCallback):
    """
    Hands the baton over every ``every`` env steps, and times the intervals in which this run held it.

    SB3 explores and samples with the global RNGs: each run keeps its own states of them across turns (starting from
    those its model was built with), so that it draws exactly what it would draw running alone.
    """

    def __init__(self, baton: Baton, name: str, every: int, rng_states: tuple):
        super().__init__()
        self.baton, self.name, self.every = baton, name, every
        self.rng_states = rng_states
        self.held_seconds = 0.0
        self.held_since = 0.0

    def take(self) -> None:
        self.baton.wait_turn(self.name)
        set_global_rng_states(self.rng_states)
        self.held_since = time.perf_counter()

    def release(self, finished: bool = False) -> None:
        if th.cuda.is_available():
            th.cuda.synchronize()  # the device's queued work belongs to this run's turn
        self.held_seconds += time.perf_counter() - self.held_since
        self.rng_states = global_rng_states()
        self.baton.hand_over(self.name, finished)

    def _on_step(self) -> bool:
        if self.n_calls % self.every == 0:
            self.release()
            self.take()
        return True


def build(
    algo_class: type, env_id: str, hyperparams: dict, seed: int, device: str = "cpu", extra: dict | None = None
) -> tuple[DQN, list[float]]:
    """A model whose train() time is summed into the returned one-element list (``extra``: its own arguments)."""
    kwargs = {**hyperparams, **(extra or {})}
    model = algo_class(POLICIES[env_id], make_env(env_id), seed=seed, verbose=0, device=device, **kwargs)
    train_seconds = [0.0]
    untimed_train = model.train

    def timed_train(*args, **kwargs) -> None:
        start = time.perf_counter()
        untimed_train(*args, **kwargs)
        if model.device.type == "cuda":
            th.cuda.synchronize()  # count the gradient steps the device still had queued
        train_seconds[0] += time.perf_counter() - start

    model.train = timed_train  # type: ignore[method-assign]
    return model, train_seconds


def run_pair(
    order: tuple[str, str],
    env_id: str,
    hyperparams: dict,
    timesteps: int,
    seed: int,
    every: int,
    device: str = "cpu",
    extra_kwargs: dict[str, dict] | None = None,
    prefill: int = 0,
    classes: dict[str, type] | None = None,
) -> dict:
    """
    Build both models (untimed), then run their learn() calls taking turns; one result dict per role.

    :param order: the roles (``"DQN"``, the baseline, and ``"OffOnDQN"``), the one that starts first
    :param extra_kwargs: per role, constructor arguments of that run only
    :param prefill: env steps each model collects first, untimed and without training (its timed run continues then)
    :param classes: per role, the algorithm (default: SB3's DQN and OffOnDQN)
    """
    names = order
    classes = {"DQN": DQN, "OffOnDQN": OffOnDQN, **(classes or {})}
    baton = Baton(*names)
    models, callbacks = {}, {}
    for name in names:
        models[name] = build(classes[name], env_id, hyperparams, seed, device, (extra_kwargs or {}).get(name))
        if prefill > 0:
            model = models[name][0]
            learning_starts, model.learning_starts = model.learning_starts, prefill
            model.learn(prefill)
            model.learning_starts = learning_starts
        callbacks[name] = TakeTurns(baton, name, every, rng_states=global_rng_states())
    cpu_seconds = {}

    def learn(name: str) -> None:
        model, callback = models[name][0], callbacks[name]
        callback.take()
        cpu_start = time.thread_time()  # torch runs on this thread (one intra-op thread)
        try:
            model.learn(total_timesteps=timesteps, callback=callback, reset_num_timesteps=prefill == 0)
        finally:
            cpu_seconds[name] = time.thread_time() - cpu_start
            callback.release(finished=True)

    gc.collect()
    load_before = os.getloadavg()
    threads = [threading.Thread(target=learn, args=(name,)) for name in names]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    load_after = os.getloadavg()

    runs = {}
    for name in names:
        model, train_seconds = models[name]
        wall, steps = callbacks[name].held_seconds, model.num_timesteps - prefill  # the timed steps only
        episode_lengths = model.env.env_method("get_episode_lengths")[0]  # from SB3's Monitor wrapper
        runs[name] = {
            "algo": name,
            "class": type(model).__name__,
            "env_steps": steps,
            "gradient_steps": model._n_updates,
            "learn_seconds": wall,
            "cpu_seconds": cpu_seconds[name],
            "train_seconds": train_seconds[0],
            "collect_seconds": wall - train_seconds[0],
            "episodes": len(episode_lengths),
            "mean_episode_length": float(np.mean(episode_lengths)) if episode_lengths else None,
            "steps_per_second": steps / wall,
            "cpu_steps_per_second": steps / cpu_seconds[name],
            "loadavg_before": load_before,
            "loadavg_after": load_after,
        }
        if isinstance(model, (OffOnDQN, OffOnQRDQN)):
            runs[name]["offon_parameters"] = {key: getattr(model, key) for key in OFFON_PARAMETERS if hasattr(model, key)}
        model.env.close()
    return runs


if __name__ == "__main__":
    args = parse_args()
    th.set_num_threads(args.threads)
    th.set_flush_denormal(args.flush_denormals)
    candidate_class, default_baseline = CANDIDATES[args.candidate]
    args.baseline = args.baseline or default_baseline
    hyperparams = dict(ZOO_HYPERPARAMS[args.env])  # one dict, passed as it is to both algorithms
    if args.train_freq is not None:
        hyperparams["train_freq"] = args.train_freq
    # The baseline's and OffOnDQN's own arguments (the "DQN" columns are the baseline's, n-step DQN's with dqn_nstep)
    baseline_class, baseline_kwargs = BASELINES[args.baseline]
    classes = {"DQN": baseline_class, "OffOnDQN": candidate_class}
    candidate_kwargs = candidate_arguments(args.mode, args.hyperparams, hyperparams)
    extra_kwargs = {"DQN": baseline_kwargs, "OffOnDQN": candidate_kwargs}
    make_env(args.env).close()  # fail early if the env (Box2D for LunarLander) is missing
    if args.device == "cuda" and not th.cuda.is_available():
        raise SystemExit("--device cuda: no CUDA device")

    result = {
        "env": args.env,
        "timesteps": args.timesteps,
        "zoo_timesteps": ZOO_TIMESTEPS[args.env],
        "repeats": args.repeats,
        "switch_every": args.switch_every,
        "seed": args.seed,
        "threads": args.threads,
        "device": args.device,
        "device_name": th.cuda.get_device_name() if args.device == "cuda" else platform.processor() or platform.machine(),
        "policy": POLICIES[args.env],
        "hyperparams": hyperparams,
        "baseline": args.baseline,
        "baseline_class": baseline_class.__name__,
        "baseline_kwargs": baseline_kwargs,
        "mode": args.mode,
        "candidate_hyperparams": args.hyperparams,
        "candidate_class": candidate_class.__name__,
        "flush_denormals": args.flush_denormals,
        "prefill": args.prefill,
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
    print(
        f"{args.env}: {args.repeats} pairs of {args.timesteps} env steps, seed {args.seed}, {args.threads} thread(s), "
        f"device {args.device} ({result['device_name']})"
    )
    print(f"hyperparams: {hyperparams}; baseline {args.baseline} {baseline_kwargs}, OffOnDQN {candidate_kwargs}")
    print(f"load average at start: {result['loadavg_start']} ({result['cpu_count']} CPUs)")

    if args.warmup_timesteps > 0:
        run_pair(
            ROLES,
            args.env,
            hyperparams,
            args.warmup_timesteps,
            args.seed,
            args.switch_every,
            args.device,
            extra_kwargs,
            classes=classes,
        )
        print(f"warm-up done ({args.warmup_timesteps} steps of each, untimed)")

    for repeat in range(args.repeats):
        order = ROLES if repeat % 2 == 0 else ROLES[::-1]
        pair = {"repeat": repeat, "order": f"{order[0]} starts"}
        pair.update(
            run_pair(
                order,
                args.env,
                hyperparams,
                args.timesteps,
                args.seed,
                args.switch_every,
                args.device,
                extra_kwargs,
                args.prefill,
                classes,
            )
        )
        for run in (pair["DQN"], pair["OffOnDQN"]):
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
    # The headline is the median of the pair ratios: the two runs of a pair saw the same machine, different pairs may not
    print(
        f"\nOffOnDQN / DQN steps/s, median of the pair ratios: {wall['pair_ratio_median']:.3f} "
        f"(min {wall['pair_ratio_min']:.3f}, max {wall['pair_ratio_max']:.3f}; ratio of the medians "
        f"{wall['ratio_of_medians']:.3f})\n"
    )
    table = markdown_table(result)
    print(table)

    if args.output is not None:
        output = Path(args.output)
        output.parent.mkdir(parents=True, exist_ok=True)
        # Classes in the settings (MinAtar's network and optimizer) are written by name
        output.write_text(json.dumps(result, indent=2, default=lambda value: getattr(value, "__name__", repr(value))) + "\n")
        output.with_suffix(".md").write_text(table + "\n")
        print(f"\nwritten: {output} and {output.with_suffix('.md')}")
