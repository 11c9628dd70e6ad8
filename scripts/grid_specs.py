"""
The grid of a benchmark (``scripts/benchmark.py``): the bundled hyperparameter sets, seeds as the command line gives
them, and one *spec* per run (a plain dict, sent to the task function that trains it): its algorithm, env, seed,
budget, evaluation, settings, device, threads and checkpoint folder, read from the set's YAML entry or from a study's
candidates (``study_file.Study``).
"""

import argparse
import functools
import importlib.util
import sys
from pathlib import Path

import yaml

# run_records.py and study_file.py sit next to this module: importable however it is loaded
sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_records import checkpoint_dir
from study_file import Study


def hyperparams_dir() -> Path:
    """The bundled hyperparameter folder of the installed ``sb3_offon`` (found without importing it: no torch here)."""
    spec = importlib.util.find_spec("sb3_offon")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("sb3_offon is not installed in this interpreter: pip install -e '.[zoo,bench]'")
    return Path(next(iter(spec.submodule_search_locations))) / "hyperparams"


def available_sets() -> list[str]:
    return ["tuned", *sorted(path.name for path in hyperparams_dir().iterdir() if path.is_dir())]


def parse_seeds(tokens: list[str]) -> list[int]:
    """``10``: seeds 0..9; ``0 3 7``: those seeds; ``5-9``: a range (inclusive)."""
    if len(tokens) == 1 and tokens[0].isdigit():
        return list(range(int(tokens[0])))
    seeds: list[int] = []
    for token in tokens:
        first, _, last = token.partition("-")
        seeds.extend(range(int(first), int(last or first) + 1))
    return sorted(set(seeds))


def seeds_text(seeds: list[int]) -> str:
    """The seeds as ranges, ``0-9`` or ``20, 23-29``: printed before a grid runs, where ``--seeds 20`` (a count, seeds
    0-19) would otherwise pass for seed 20."""
    ranges: list[list[int]] = []
    for seed in sorted(seeds):
        if ranges and seed == ranges[-1][1] + 1:
            ranges[-1][1] = seed
        else:
            ranges.append([seed, seed])
    return ", ".join(str(first) if first == last else f"{first}-{last}" for first, last in ranges)


def config_file(hyperparams_set: str, algo: str) -> Path:
    """The YAML file the zoo reads for ``algo`` in the set (a former name, ``hyperparams/aliases.yml``, reads its new
    name's)."""
    folder = hyperparams_dir()
    algo = aliases(folder).get(algo, algo)
    return folder / f"{algo}.yml" if hyperparams_set == "tuned" else folder / hyperparams_set / f"{algo}.yml"


@functools.cache
def aliases(folder: Path) -> dict[str, str]:
    """The former names of algorithms (``hyperparams/aliases.yml``), read once."""
    return yaml.safe_load((folder / "aliases.yml").read_text())


def build_specs(args: argparse.Namespace) -> list[dict]:
    """One spec per (algo, env, seed); the budget and settings are read from the set's YAML entry."""
    specs = []
    for algo in args.algos:
        path = config_file(args.set, algo)
        if not path.is_file():
            raise SystemExit(f"No hyperparameter file {path} for --algo {algo} in the '{args.set}' set")
        entries = yaml.safe_load(path.read_text())
        for env in args.envs:
            entry = entries.get(env)
            if entry is None and "atari" in entries:
                # An Atari game without an entry of its own reads the set's `atari` entry, as the zoo does (imported
                # here: the package brings torch, which the runner's driver needs only for such a grid)
                from sb3_offon.atari import looks_like_atari

                entry = entries["atari"] if looks_like_atari(env) else None
            if entry is None:
                known = sorted(key for key in entries if key not in ("default", "atari"))
                raise SystemExit(f"{path} has no entry for {env}: {known}")
            yaml_budget = int(float(entry["n_timesteps"]))
            n_timesteps = args.n_timesteps or yaml_budget
            eval_freq = args.eval_freq or max(n_timesteps // args.n_evals, 1)
            if eval_freq > n_timesteps:
                raise SystemExit(f"--eval-freq {eval_freq} is above the budget of {env} ({n_timesteps}): no evaluation")
            hyperparams = list(args.hyperparams)
            # The paper's epsilon reaches its final value at a fixed timestep (exploration_fraction = 1919 / budget
            # in the YAML): keep that timestep when the budget is overridden (the YAML's own instruction)
            fraction = entry.get("exploration_fraction")
            overridden = any(item.startswith("exploration_fraction:") for item in hyperparams)
            if args.set != "tuned" and n_timesteps != yaml_budget and fraction is not None and not overridden:
                hyperparams.append(f"exploration_fraction:{min(1.0, float(fraction) * yaml_budget / n_timesteps):.6g}")
            for seed in args.seeds:
                specs.append(
                    {
                        "set": args.set,
                        "grid": args.name or args.set,
                        "algo": algo,
                        **({"run_name": args.run_names[algo]} if algo in args.run_names else {}),
                        "env": env,
                        "seed": seed,
                        "n_timesteps": n_timesteps,
                        "eval_freq": eval_freq,
                        "eval_episodes": args.eval_episodes,
                        "hyperparams": hyperparams,
                        "device": args.device or default_device(entry.get("policy", "MlpPolicy")),
                        "threads": args.threads,
                        "timeout": args.timeout,
                        "checkpoint_freq": eval_freq if args.checkpoint_freq is None else args.checkpoint_freq,
                    }
                )
                if specs[-1]["checkpoint_freq"] > 0:
                    specs[-1]["checkpoint_dir"] = str(checkpoint_dir(args.root, specs[-1]).resolve())
    return specs


def candidate_specs(args: argparse.Namespace) -> list[dict]:
    """
    The runs of a study that chooses among candidates (``--study`` with ``candidates``; ``--algos`` names candidates):
    each candidate's algorithm with its settings, on its envs and seeds, into its folder, as ``study_file.Study``
    resolves them; ``--seeds`` keeps those of its seeds.
    """
    study: Study = args.study_file
    specs = []
    for name in args.algos:
        algo = study.algo_of(name)
        for env in study.envs_for(name):
            if env not in args.envs:
                continue
            one = argparse.Namespace(**vars(args))
            one.algos, one.envs = [algo], [env]
            one.seeds = [seed for seed in study.seeds_for(name, env) if not args.seeds_given or seed in args.seeds]
            one.hyperparams = study.hyperparams_for(name, env)
            one.name, run_name = study.source(name, env)
            one.eval_episodes = study.episodes_for(env, args.eval_episodes)
            one.run_names = {algo: run_name} if run_name != algo else {}
            specs += build_specs(one)
    return specs


def default_device(policy: str) -> str:
    """Small MLPs train faster on one CPU thread per run than sharing a GPU (about 5x, measured: README, Speed); CNNs
    the other way round."""
    return "cpu" if policy == "MlpPolicy" else "auto"
