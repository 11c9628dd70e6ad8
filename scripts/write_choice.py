"""
Write ``hyperparams/offon_lambda_choice.yml``: ``offon_lambda.yml`` with the target settings of the candidate that the
lambda-return search of issue 27 chose, under a name of its own (``--algo offon_lambda_choice``) for the head-to-head
on seeds 20-29.

The choice is read from ``results/search/summary.md`` (written by ``python scripts/search.py report``), never typed in:
a round that chose none leaves nothing to write, and the script says so. Only the target lines of ``offon_lambda.yml``
change, so its comments, its zoo settings and its YAML anchors stay as they are; a test checks that every entry is
``offon_lambda.yml``'s with the choice's settings.

Usage::

    python scripts/search.py report && python scripts/write_choice.py
"""

import argparse
import re
import sys
import textwrap
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import search

CHOICE_LINE = re.compile(r"^\*\*Choice\*\* \(the highest mean normalised AUC [^)]*\): (\w+),", re.M)
# What chose, by round (stated before each round's runs: scripts/search.py's docstring)
CRITERIA = {
    3: "the highest mean normalised AUC over the four benchmark tasks among the candidates whose mean final return is "
    "nowhere more than 2% of the task's range below DQN's",
    5: "the highest mean normalised AUC over the four benchmark tasks among the candidates that no task shows below "
    "DQN, by the 95% bootstrap interval of the difference of the mean final returns against 2% of the task's range",
}
CRITERIA[4] = CRITERIA[3]


def chosen_candidate(summary: str) -> tuple[str, str] | None:
    """The last round of the summary whose choice is a lambda-return candidate, and that candidate (None if none chose)."""
    chosen = None
    for section in summary.split("\n## ")[1:]:
        match = CHOICE_LINE.search(section)
        round_name = re.match(r"Round \d+", section)
        if match and round_name and search.BY_NAME[match.group(1)].algo == "offon_lambda":
            chosen = (round_name.group(0), match.group(1))
    return chosen


def describe(overrides: dict[str, str]) -> list[str]:
    """The header's lines on lambda (delta1) and the trace cuts (delta2)."""
    lam0, lam1, fraction = overrides["mc_initial_prob"], overrides["mc_final_prob"], float(overrides["mc_fraction"])
    if lam0 == lam1:
        lam = f"lambda = delta1 = {lam0} throughout training."
    else:
        period = "over training" if fraction == 1.0 else f"over the first {fraction:.0%} of training, then {lam1}"
        lam = f"lambda = delta1 from {lam0} to {lam1} {period}."
    cut0, cut1 = overrides["qlearning_initial_prob"], overrides["qlearning_final_prob"]
    cuts = {
        "1.0": "delta2 = 1: Watkins's Q(lambda), the trace is cut after every non-greedy action.",
        "0.0": "delta2 = 0: Peng's Q(lambda), the trace is never cut.",
    }
    return [lam, cuts[cut0] if cut0 == cut1 else f"delta2 from {cut0} to {cut1}."]


def seeds_text(candidate: search.Candidate) -> str:
    """The tuning seeds ``candidate`` was judged on: "0-4", or "0-4 (FrozenLake-v1: 0-9)" where a task had others."""
    ranges = {env: f"{min(seeds)}-{max(seeds)}" for env in candidate.envs for seeds in [candidate.seeds_on(env)]}
    common = max(set(ranges.values()), key=list(ranges.values()).count)
    others = ", ".join(f"{env}: {text}" for env, text in ranges.items() if text != common)
    return f"{common} ({others})" if others else common


def comment(text: str, indent: str = "# ") -> str:
    """``text`` as YAML comment lines of at most 120 characters."""
    return textwrap.fill(text, width=120, initial_indent=indent, subsequent_indent=indent, break_on_hyphens=False)


def choice_yaml(name: str, round_name: str, lambda_yaml: str) -> str:
    """``offon_lambda.yml``'s text with candidate ``name``'s target settings and a header saying where they came from."""
    candidate = search.BY_NAME[name]
    if candidate.per_env or candidate.algo != "offon_lambda":
        raise ValueError(f"{name}: only an offon_lambda candidate with one setting for every task can be written")
    overrides = dict(item.split(":", 1) for item in candidate.hyperparams)
    body = lambda_yaml[lambda_yaml.index("# Default hyperparameters") :]
    for key, value in overrides.items():
        # The first occurrence is the `&targets` block that every entry merges
        body, count = re.subn(rf"^(    {key}: ).*$", rf"\g<1>{value}", body, count=1, flags=re.M)
        if count != 1:
            raise ValueError(f"offon_lambda.yml has no `{key}` line in its target block")
    lam, cuts = describe(overrides)
    chosen = (
        f"The chosen candidate, `{name}` ({candidate.description}), by the criterion stated before the runs "
        f"({CRITERIA[int(round_name.split()[-1])]}):"
    )
    origin = (
        'Off-On lambda, the search\'s choice (`--algo offon_lambda_choice`): OffOnDQN with mc_mixing="lambda" and the '
        f"one setting of lambda and delta2 that {round_name} of the search (issue 27) chose for every task on tuning seeds "
        f"{seeds_text(candidate)} (results/search/README.md, results/search/summary.md), under a name of its own for the "
        "head-to-head on seeds 20-29."
    )
    header = f"""{comment(origin)}
# Written by scripts/write_choice.py.
#
# DQN settings: rl-baselines3-zoo 2.9.2's tuned `dqn` entries (copied in dqn.yml next to this file), values
# unchanged, as for every candidate of the search.
#
{comment(chosen)}
{comment(", ".join(f"{key}={value}" for key, value in overrides.items()), indent="#   ")}
#   {lam}
#   {cuts}
# Every other line is offon_lambda.yml's (a test checks both).

"""
    return header + body


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--summary", type=Path, default=Path("results/search/summary.md"))
    parser.add_argument("--out", type=Path, default=search.benchmark.config_file("tuned", "offon_lambda_choice"))
    args = parser.parse_args(argv)
    chosen = chosen_candidate(args.summary.read_text())
    if chosen is None:
        print(f"{args.summary}: no round of the lambda-return search has chosen a candidate; nothing written", file=sys.stderr)
        return 1
    round_name, name = chosen
    lambda_yaml = search.benchmark.config_file("tuned", "offon_lambda").read_text()
    args.out.write_text(choice_yaml(name, round_name.lower(), lambda_yaml))
    print(f"{args.out}: {name} ({round_name})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
