"""
Pytest plugin that runs Stable-Baselines3's own test suite with ``OffOnDQN`` in place of ``DQN``.

Load it with ``-p sb3_offon_plugin`` (this folder on ``PYTHONPATH``) when running SB3's test files; it is not a
``conftest.py`` on purpose, so that this project's own test run never picks it up and never swaps SB3's ``DQN``.
``tests/test_sb3_suite.py`` fetches SB3's tests (the sdist of the installed version) and runs them with it.

What it does:

- Before any test module is imported (plugins load before collection), ``stable_baselines3.DQN`` and
  ``stable_baselines3.dqn.DQN`` -- the only places SB3's tests import ``DQN`` from, as ``from stable_baselines3
  import DQN`` or ``sb3.DQN`` -- are set to ``sb3_offon.OffOnDQN``. ``stable_baselines3.dqn.dqn.DQN``, the defining
  module, keeps SB3's class (``OffOnDQN`` subclasses it).
- ``--offon-dqn-only`` keeps the tests that exercise DQN: a test parametrised with algorithm classes is kept for its
  ``OffOnDQN`` cases only; a test with no algorithm parameter is kept if its source names ``DQN``. Every other test
  is deselected. (A ``-k DQN`` filter would miss the tests that build a DQN without it being in their id, such as
  ``test_callbacks.py::test_eval_success_logging``.)
- Tests listed in ``DQN_RUN_NAME`` run with ``OffOnDQN.learn``'s default ``tb_log_name`` set to ``"DQN"``: they
  read the tensorboard run folder by the name of ``DQN.learn``'s default (``DQN_1``), while ``OffOnDQN`` names its
  runs after itself (``OffOnDQN_1``), as every SB3 and sb3-contrib algorithm does. What they check (the events in
  that run) is then checked for ``OffOnDQN``. Keep this list short and exact; anything else that fails is a bug.
"""

import functools
import inspect
import re
from collections.abc import Iterator
from typing import Any

import pytest
import stable_baselines3
import stable_baselines3.dqn
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.dqn.dqn import DQN as SB3_DQN

from sb3_offon import OffOnDQN

# Test node ids (relative to SB3's tests folder) that read the tensorboard run folder "DQN_1" by name
DQN_RUN_NAME = {"test_callbacks.py::test_eval_callback_logs_are_written_with_the_correct_timestep"}

_NAMES_DQN = re.compile(r"\bDQN\b")


def swap_dqn() -> None:
    """Make ``from stable_baselines3 import DQN`` (and ``stable_baselines3.dqn``) give ``OffOnDQN``."""
    assert issubclass(OffOnDQN, SB3_DQN)
    stable_baselines3.DQN = OffOnDQN  # type: ignore[misc]
    stable_baselines3.dqn.DQN = OffOnDQN  # type: ignore[misc]


# At import: ``-p`` loads this module before the test modules are collected (and so imported)
swap_dqn()


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("sb3_offon")
    group.addoption(
        "--offon-dqn-only",
        action="store_true",
        default=False,
        help="keep only the tests that exercise DQN (now OffOnDQN)",
    )


def pytest_configure(config: pytest.Config) -> None:
    swap_dqn()  # in case something re-imported stable_baselines3 in between
    config.addinivalue_line("markers", "sb3_offon: test of SB3's suite run with OffOnDQN in place of DQN")


def pytest_report_header(config: pytest.Config) -> str:
    return f"sb3_offon plugin: stable_baselines3.DQN is {stable_baselines3.DQN.__module__}.{stable_baselines3.DQN.__name__}"


def _algorithm_classes(value: Any) -> list[type]:
    """The algorithm classes in a parameter value (itself, or the items of a tuple, list or dict)."""
    if isinstance(value, type) and issubclass(value, BaseAlgorithm):
        return [value]
    if isinstance(value, (tuple, list)):
        return [cls for item in value for cls in _algorithm_classes(item)]
    if isinstance(value, dict):
        return [cls for item in value.values() for cls in _algorithm_classes(item)]
    return []


def _source_names_dqn(item: pytest.Item) -> bool:
    function = getattr(item, "function", None)
    if function is None:
        return False
    try:
        source = inspect.getsource(function)
    except (OSError, TypeError):
        return False
    return bool(_NAMES_DQN.search(source))


def exercises_dqn(item: pytest.Item) -> bool:
    callspec = getattr(item, "callspec", None)
    params = callspec.params if callspec is not None else {}
    classes = [cls for value in params.values() for cls in _algorithm_classes(value)]
    if classes:
        return any(issubclass(cls, SB3_DQN) for cls in classes)
    return _source_names_dqn(item)


def _relative_nodeid(item: pytest.Item) -> str:
    # "tests/test_x.py::name[...]" or "test_x.py::name[...]", depending on the rootdir: keep from the file name
    path, sep, rest = item.nodeid.partition("::")
    return path.rsplit("/", 1)[-1] + sep + rest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not config.getoption("offon_dqn_only"):
        return
    selected, deselected = [], []
    for item in items:
        if exercises_dqn(item):
            item.add_marker(pytest.mark.sb3_offon)
            selected.append(item)
        else:
            deselected.append(item)
    if deselected:
        config.hook.pytest_deselected(items=deselected)
    items[:] = selected


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    if _relative_nodeid(item).split("[", 1)[0] not in DQN_RUN_NAME:
        return (yield)
    # partialmethod: an explicit tb_log_name of the test still wins
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(OffOnDQN, "learn", functools.partialmethod(OffOnDQN.learn, tb_log_name="DQN"))
        return (yield)
