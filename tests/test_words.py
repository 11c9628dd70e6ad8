"""The repository speaks of the software, its studies and their evidence: no words about how the work was organised."""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Built from parts, so that this file does not match itself. Links to other projects' public issues ("issues/123")
# do not match: the number must follow the word and a space.
WORDS = re.compile(
    "|".join(
        [
            r"\b" + "ses" + r"sions?\b",
            r"\blent " + r"machines?\b",
            r"\bdevice " + r"machines?\b",
            r"\biss" + r"ues? #?[0-9]+",
        ]
    ),
    re.IGNORECASE,
)


def text_files() -> list[Path]:
    """Every tracked file that reads as UTF-8 text (git's list; without git, every file under the checkout)."""
    try:
        listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
        paths = [ROOT / name for name in listed]
    except (OSError, subprocess.CalledProcessError):
        paths = [path for path in ROOT.rglob("*") if ".git" not in path.parts and ".venv" not in path.parts]
    files = []
    for path in paths:
        if not path.is_file():
            continue
        try:
            path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        files.append(path)
    return files


def test_the_words_pattern_finds_what_it_is_for() -> None:
    examples = ["in the ninth Ses" + "sion", "Iss" + "ue 27, step 3", "(iss" + "ue #13)", "on a lent " + "machine"]
    for sentence in [*examples, "the device " + "machine"]:
        assert WORDS.search(sentence), sentence
    for sentence in ("https://github.com/DLR-RM/stable-baselines3/issues/1234", "the device: cpu", "lent to users"):
        assert not WORDS.search(sentence), sentence


def test_no_words_about_how_the_work_was_organised() -> None:
    files = text_files()
    assert len(files) > 100, "the repository's files were found"
    found = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}"
        for path in files
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if WORDS.search(line)
    ]
    assert not found, "\n".join(found)
