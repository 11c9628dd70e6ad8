"""
The Python examples of the README and of the documentation run as printed: each page's ```python blocks are executed in
order in one namespace (as a reader pastes them, a later block using an earlier one's imports), in a fresh folder, with
training cut to a few hundred steps so that the whole file takes seconds. A renamed argument, a moved import or a
removed class fails here before a user meets it.
"""

import re
from pathlib import Path
from typing import Any

import pytest
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# Enough env steps to pass the default learning start (100) and train a few times, few enough to take a second
STEPS = 300
# The resume example goes on from a run cut off after its first checkpoint (10,000 steps): it is only compiled here;
# tests/test_resume.py runs the same calls on an interrupted run
COMPILED_ONLY = ("Checkpoint.latest",)


def python_examples() -> list[Any]:
    """One parameter per page with examples: its blocks, in order."""
    examples = []
    for page in PAGES:
        blocks = re.findall(r"^```python\n(.*?)^```", page.read_text(encoding="utf-8"), re.S | re.M)
        if blocks:
            examples.append(pytest.param(blocks, id=str(page.relative_to(ROOT))))
    return examples


EXAMPLES = python_examples()


def test_the_pages_have_examples() -> None:
    # The pattern above finds them (a change of fence style would otherwise leave this file testing nothing)
    assert sum(len(example.values[0]) for example in EXAMPLES) >= 10


@pytest.mark.parametrize("blocks", EXAMPLES)
def test_the_examples_run(blocks: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    learn = OffPolicyAlgorithm.learn
    trained: list[int] = []

    def short_learn(self: OffPolicyAlgorithm, total_timesteps: int, *args: Any, **kwargs: Any) -> Any:
        trained.append(total_timesteps)
        return learn(self, min(total_timesteps, STEPS), *args, **kwargs)

    monkeypatch.setattr(OffPolicyAlgorithm, "learn", short_learn)
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, Any] = {"__name__": "__example__"}
    for code in blocks:
        compiled = compile(code, "<example>", "exec")
        if any(marker in code for marker in COMPILED_ONLY):
            continue
        calls = len(trained)
        exec(compiled, namespace)
        if ".learn(" in code:
            assert len(trained) > calls, "the example trains, through OffPolicyAlgorithm.learn"
