"""
The report of ``scripts/bench_speed.py``: the summary of a pair of algorithms' speeds (the median of the pairs' ratios,
the headline, with their range) and the Markdown table written beside the JSON.
"""

import statistics

# What the "DQN" columns are, by ``--baseline``
BASELINE_NAMES = {
    "dqn": "SB3's DQN",
    "dqn_nstep": "SB3's DQN with n_steps=10 (n-step DQN)",
    "offon_defaults": "OffOnDQN with its defaults",
    "qrdqn": "sb3_offon.qrdqn.QRDQN (QR-DQN)",
    "qrdqn_nstep": "sb3_offon.qrdqn.QRDQN with n_steps=3 (n-step QR-DQN)",
    "offon_qrdqn_defaults": "OffOnQRDQN with its defaults",
}


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
        f"{result['env']}, {result['timesteps']} env steps per run, {result['repeats']} pairs taking turns every "
        f"{result['switch_every']} env steps, "
        f"seed {result['seed']}, {result['policy']} on {result['device']} ({result['device_name']}), "
        f"baseline {result.get('baseline', 'dqn')}, OffOnDQN targets {result.get('mode', 'paper')}"
        f"{''.join(f' {key}={value!r}' for key, value in result.get('candidate_hyperparams', {}).items())}, "
        f"a gradient step every {result['hyperparams']['train_freq']} env steps, "
        f"prefill {result.get('prefill', 0)} untimed steps, "
        f"{result['threads']} torch thread(s), load average "
        f"{result['loadavg_start'][0]:.2f} at start / {result['loadavg_end'][0]:.2f} at end ({result['cpu_count']} CPUs), "
        f"sb3_offon {result['git']}, SB3 {result['versions']['stable_baselines3']}, torch {result['versions']['torch']}",
        "",
        *(
            [f"The DQN columns and rows are the baseline's: {BASELINE_NAMES[result['baseline']]}.", ""]
            if result.get("baseline", "dqn") != "dqn"
            else []
        ),
        *(
            [f"The OffOnDQN columns and rows are {result['candidate_class']}'s.", ""]
            if result.get("candidate_class", "OffOnDQN") != "OffOnDQN"
            else []
        ),
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
        # each column's own median: the ratio column's is the median of the pair ratios (the headline)
        f"| **median** | | **{wall['dqn_median']:.0f}** | **{wall['offon_median']:.0f}** "
        f"| **{wall['pair_ratio_median']:.3f}** | **{cpu['dqn_median']:.0f}** | **{cpu['offon_median']:.0f}** "
        f"| **{cpu['pair_ratio_median']:.3f}** |"
    )
    lines += [
        "",
        f"Pair ratios (wall): median {wall['pair_ratio_median']:.3f}, min {wall['pair_ratio_min']:.3f}, "
        f"max {wall['pair_ratio_max']:.3f}; (CPU): median {cpu['pair_ratio_median']:.3f}, min {cpu['pair_ratio_min']:.3f}, "
        f"max {cpu['pair_ratio_max']:.3f}. Ratio of the medians (pairs may have seen different machine speeds): "
        f"wall {wall['ratio_of_medians']:.3f}, CPU {cpu['ratio_of_medians']:.3f}.",
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
