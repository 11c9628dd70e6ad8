"""
``results/`` holds data and the reports that read it, never code: a tool that any study can use lives in ``scripts/``
(tested and documented there), and one that a single study needed once stays in git history.
"""

import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Source files of the languages a tool might be written in, and notebooks
CODE_SUFFIXES = {".py", ".pyx", ".ipynb", ".sh", ".bash", ".zsh", ".ps1", ".bat", ".cmd", ".r", ".jl", ".js", ".pl", ".rb"}


def is_code(path: Path) -> bool:
    """A file is code when its suffix says so, when it is executable, or when it opens with a ``#!`` line."""
    if path.suffix.lower() in CODE_SUFFIXES or path.stat().st_mode & 0o111:
        return True
    with open(path, "rb") as file:
        return file.read(2) == b"#!"


def result_files() -> list[Path]:
    """Every tracked file under ``results/`` (git's list; without git, every file there)."""
    try:
        listed = subprocess.run(
            ["git", "ls-files", "results"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.splitlines()
        paths = [ROOT / name for name in listed]
    except (OSError, subprocess.CalledProcessError):
        paths = list((ROOT / "results").rglob("*"))
    return [path for path in paths if path.is_file()]


def test_the_code_test_finds_what_it_is_for(tmp_path: Path) -> None:
    examples = {"measure.py": b"import torch\n", "run_slice.sh": b"set -u\n", "notes.ipynb": b"{}", "tool": b"#!/bin/sh\n"}
    for name, content in examples.items():
        (tmp_path / name).write_bytes(content)
        assert is_code(tmp_path / name), name
    executable = tmp_path / "run"
    executable.write_bytes(b"python3 x\n")
    os.chmod(executable, 0o755)
    assert is_code(executable)
    for name, content in {"table.md": b"| a |\n", "done.json": b"{}", "train.log": b"#1\n", "x.npz": b"PK"}.items():
        (tmp_path / name).write_bytes(content)
        assert not is_code(tmp_path / name), name


def test_no_results_folder_holds_code() -> None:
    files = result_files()
    assert len(files) > 100, "the results were found"
    found = [str(path.relative_to(ROOT)) for path in files if is_code(path)]
    assert not found, "code under results/ (a tool for any study goes to scripts/, a one-off to git history): " + ", ".join(
        found
    )
