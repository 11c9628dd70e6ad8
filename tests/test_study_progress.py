"""Where the README, the benchmarks page or a report says how far an unfinished study has come ("6 of 75 runs in"), the
count is the number of the study's finished runs under ``results/raw``, as its report counts them."""

import re
from pathlib import Path

import pytest
from helpers import load_script

ROOT = Path(__file__).resolve().parents[1]
study_file = load_script("study_file")
load_script("study")  # puts scripts/ on the import path, which rule.py's own imports need
rule = load_script("rule")
STUDIES = sorted((ROOT / "benchmarks").glob("*.yml"))


def stated_counts(text: str, name: str, total: int, whole_file: bool) -> list[int]:
    """Every "N of <total>" in the paragraphs (and table rows) of ``text`` that name the study, or in all of it."""
    marks = (f"`{name}`", f"{name}.yml", f"results/{name}/")
    parts = [text]
    if not whole_file:  # paragraphs, and each table row apart: a row names its study, a paragraph somewhere in it
        parts = [part for part in re.split(r"\n\s*\n|\n(?=\|)", text) if any(mark in part for mark in marks)]
    pattern = re.compile(rf"\b(\d+) of {total}\b")
    return [int(count) for part in parts for count in pattern.findall(part)]


def test_stated_counts_reads_the_study_s_paragraphs_only() -> None:
    text = (
        "Intro: 3 of 75 things.\n\n"
        "The study `atari100k` is under way: 6 of 75 in,\nsee results/atari100k/README.md.\n\n"
        "| `atari100k_qr` | 7 of 75 runs in |\n"
        "| `atari100k` | 5 of 75 runs in |\n"
    )
    assert stated_counts(text, "atari100k", 75, whole_file=False) == [6, 5]
    assert stated_counts("Runs in: 6 of 75, and 4 of 50", "x", 75, whole_file=True) == [6]


@pytest.mark.parametrize("path", STUDIES, ids=[path.stem for path in STUDIES])
def test_an_unfinished_study_s_stated_progress_is_its_finished_runs(path: Path) -> None:
    study = study_file.Study.read(path)
    if study.candidates:
        pytest.skip("a study that chooses among candidates: its runs are counted by scripts/selection.py")
    # The runs the study's report counts (scripts/study.py: "incomplete (N runs missing)")
    runs, _ = rule.study_runs(study, ROOT / "results" / "raw")
    missing = rule.missing_runs(study, runs)
    total = sum(len(study.seeds_for(algo, env)) for algo in study.algos for env in study.envs_for(algo))
    finished = total - missing
    if not missing:
        pytest.skip(f"{study.name}: every run is in")
    report = ROOT / (study.out or f"results/{study.name}") / "README.md"
    documents = [(ROOT / "README.md", False), (ROOT / "docs" / "benchmarks.md", False), (report, True)]
    for document, whole_file in documents:
        if document.is_file():
            for count in stated_counts(document.read_text(), study.name, total, whole_file):
                assert count == finished, f"{document.relative_to(ROOT)} says {count} of {total} runs of {study.name}"
