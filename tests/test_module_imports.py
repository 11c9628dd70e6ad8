"""The package's modules import each other without a circle (type-only imports included)."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "sb3_offon"


def imported_modules(path: Path) -> set[str]:
    """The ``sb3_offon`` modules a file imports anywhere in it (under ``if TYPE_CHECKING:`` too)."""
    modules = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("sb3_offon"):
            modules.add(node.module)
        elif isinstance(node, ast.Import):
            modules.update(alias.name for alias in node.names if alias.name.startswith("sb3_offon"))
    return modules


def import_graph(folder: Path) -> dict[str, set[str]]:
    """Module -> the modules of the same folder it imports."""
    prefix = "sb3_offon." + ".".join(folder.relative_to(PACKAGE).parts)
    names = {path.stem for path in folder.glob("*.py") if path.stem != "__init__"}
    graph = {}
    for name in names:
        imported = imported_modules(folder / f"{name}.py")
        graph[name] = {module.removeprefix(prefix + ".") for module in imported} & names
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A circle of imports, as the list of its modules, or None."""
    state: dict[str, str] = {}

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = "open"
        for neighbour in sorted(graph[node]):
            if state.get(neighbour) == "open":
                return [*path[path.index(neighbour) :], neighbour] if neighbour in path else [node, neighbour]
            if neighbour not in state and (cycle := visit(neighbour, [*path, neighbour])):
                return cycle
        state[node] = "done"
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start, [start])):
            return cycle
    return None


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


@pytest.mark.parametrize("folder", ["common", "offon_dqn", "offon_qrdqn"])
def test_no_import_circle(folder):
    assert find_cycle(import_graph(PACKAGE / folder)) is None
