"""
Pytest plugin that runs a library's own tests of an algorithm with this package's drop-in in its place: SB3's tests of
``DQN`` with ``OffOnDQN``, sb3-contrib's tests of ``QRDQN`` with ``OffOnQRDQN`` or with ``sb3_offon.qrdqn.QRDQN``.

Load it with ``-p sb3_offon_plugin`` (this folder on ``PYTHONPATH``) when running those test files; it is not a
``conftest.py`` on purpose, so that this project's own test run never picks it up and never swaps a class.
``tests/test_sb3_suite.py`` fetches the libraries' tests (the sdist of the installed version) and runs them with it.

What it does:

- ``SB3_OFFON_SWAP`` (an environment variable: ``OffOnDQN``, the default, ``OffOnQRDQN`` or ``QRDQN``) names the class
  swapped in. Before any test module is imported (plugins load before collection), the names the tests import the
  original from -- ``stable_baselines3.DQN`` and ``stable_baselines3.dqn.DQN``; ``sb3_contrib.QRDQN`` and
  ``sb3_contrib.qrdqn.QRDQN`` -- are set to it. The defining modules keep the originals (the drop-ins subclass them).
- ``--swapped-only`` keeps the tests that exercise the original: a test parametrised with algorithm classes is kept
  for its swapped-in cases only; a test with no algorithm parameter is kept if its source names the original. Every
  other test is deselected. (A ``-k DQN`` filter would miss the tests that build a DQN without it being in their id,
  such as SB3's ``test_callbacks.py::test_eval_success_logging``.)
- Tests listed in ``RUN_NAME_TESTS`` run with the drop-in's ``learn`` default ``tb_log_name`` set to the original's
  name: they read the tensorboard run folder by the name of the original's default (``DQN_1``), while a drop-in names
  its runs after itself (``OffOnDQN_1``), as every SB3 and sb3-contrib algorithm does. What they check (the events in
  that run) is then checked for the drop-in. Keep this list short and exact; anything else that fails is a bug.
"""

import functools
import inspect
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest
import sb3_contrib
import sb3_contrib.qrdqn
import stable_baselines3
import stable_baselines3.dqn
from sb3_contrib.qrdqn.qrdqn import QRDQN as CONTRIB_QRDQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.dqn.dqn import DQN as SB3_DQN

from sb3_offon import OffOnDQN, OffOnQRDQN
from sb3_offon.qrdqn import QRDQN


@dataclass(frozen=True)
class Swap:
    """A drop-in put where a library's tests import an original class from."""

    original: type[BaseAlgorithm]
    drop_in: type[BaseAlgorithm]
    modules: tuple[Any, ...]  # the modules whose attribute of the original's name becomes the drop-in
    run_name_tests: frozenset[str] = frozenset()  # see the module's docstring

    def apply(self) -> None:
        assert issubclass(self.drop_in, self.original)
        for module in self.modules:
            setattr(module, self.original.__name__, self.drop_in)


SWAPS = {
    "OffOnDQN": Swap(
        SB3_DQN,
        OffOnDQN,
        (stable_baselines3, stable_baselines3.dqn),
        # Test node ids (relative to SB3's tests folder) that read the tensorboard run folder "DQN_1" by name
        frozenset({"test_callbacks.py::test_eval_callback_logs_are_written_with_the_correct_timestep"}),
    ),
    "OffOnQRDQN": Swap(CONTRIB_QRDQN, OffOnQRDQN, (sb3_contrib, sb3_contrib.qrdqn)),
    "QRDQN": Swap(CONTRIB_QRDQN, QRDQN, (sb3_contrib, sb3_contrib.qrdqn)),
}
SWAP = SWAPS[os.environ.get("SB3_OFFON_SWAP", "OffOnDQN")]
_NAMES_ORIGINAL = re.compile(rf"\b{SWAP.original.__name__}\b")

# At import: ``-p`` loads this module before the test modules are collected (and so imported)
SWAP.apply()


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("sb3_offon")
    group.addoption(
        "--swapped-only",
        action="store_true",
        default=False,
        help=f"keep only the tests that exercise {SWAP.original.__name__} (now {SWAP.drop_in.__name__})",
    )


def pytest_configure(config: pytest.Config) -> None:
    SWAP.apply()  # in case something re-imported the library in between
    config.addinivalue_line("markers", f"sb3_offon: test run with {SWAP.drop_in.__name__} in place of the original")


def pytest_report_header(config: pytest.Config) -> str:
    return f"sb3_offon plugin: {SWAP.original.__name__} is {SWAP.drop_in.__module__}.{SWAP.drop_in.__name__}"


def _algorithm_classes(value: Any) -> list[type]:
    """The algorithm classes in a parameter value (itself, or the items of a tuple, list or dict)."""
    if isinstance(value, type) and issubclass(value, BaseAlgorithm):
        return [value]
    if isinstance(value, (tuple, list)):
        return [cls for item in value for cls in _algorithm_classes(item)]
    if isinstance(value, dict):
        return [cls for item in value.values() for cls in _algorithm_classes(item)]
    return []


def _source_names_original(item: pytest.Item) -> bool:
    function = getattr(item, "function", None)
    if function is None:
        return False
    try:
        source = inspect.getsource(function)
    except (OSError, TypeError):
        return False
    return bool(_NAMES_ORIGINAL.search(source))


def _parametrised_with_classes(item: pytest.Item) -> bool:
    """Whether one of the test's parametrisations lists algorithm classes (a case may hold another value there)."""
    return any(_algorithm_classes(list(mark.args[1])) for mark in item.iter_markers("parametrize") if len(mark.args) > 1)


def exercises_original(item: pytest.Item) -> bool:
    callspec = getattr(item, "callspec", None)
    params = callspec.params if callspec is not None else {}
    classes = [cls for value in params.values() for cls in _algorithm_classes(value)]
    if classes:
        return any(issubclass(cls, SWAP.original) for cls in classes)
    if _parametrised_with_classes(item):
        return False  # a case of another kind in a list of algorithms (sb3-contrib's "ars_multi")
    return _source_names_original(item)


def _relative_nodeid(item: pytest.Item) -> str:
    # "tests/test_x.py::name[...]" or "test_x.py::name[...]", depending on the rootdir: keep from the file name
    path, sep, rest = item.nodeid.partition("::")
    return path.rsplit("/", 1)[-1] + sep + rest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not config.getoption("swapped_only"):
        return
    selected, deselected = [], []
    for item in items:
        if exercises_original(item):
            item.add_marker(pytest.mark.sb3_offon)
            selected.append(item)
        else:
            deselected.append(item)
    if deselected:
        config.hook.pytest_deselected(items=deselected)
    items[:] = selected


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    if _relative_nodeid(item).split("[", 1)[0] not in SWAP.run_name_tests:
        return (yield)
    # partialmethod: an explicit tb_log_name of the test still wins
    with pytest.MonkeyPatch.context() as patch:
        learn = SWAP.drop_in.learn
        patch.setattr(SWAP.drop_in, "learn", functools.partialmethod(learn, tb_log_name=SWAP.original.__name__))
        return (yield)
