"""
Without the ``zoo`` extra, the command lines stop with one line naming the missing module and the install command.

The extra is hidden from subprocesses, not uninstalled: a ``sitecustomize`` module on their ``PYTHONPATH`` puts an
import finder in front of the others that reports ``rl_zoo3`` missing, with the error Python raises for an absent package.
The console scripts are run as pip installed them.
"""

import os
import subprocess
import sys
import sysconfig
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from sb3_offon.extras import INSTALL_HINT, zoo_required

TIMEOUT = 300
HIDE_ZOO = """
import sys


class HideZoo:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] == "rl_zoo3":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


sys.meta_path.insert(0, HideZoo())
"""


def test_zoo_modules_become_one_line() -> None:
    for name in ("rl_zoo3", "optuna"):
        with pytest.raises(SystemExit) as raised, zoo_required():
            raise ModuleNotFoundError(f"No module named '{name}'", name=name)
        message = str(raised.value.code)
        assert f"'{name}'" in message
        assert INSTALL_HINT in message
        assert "\n" not in message


@pytest.mark.parametrize("name", ["sb3_offon.no_such_module", "torch", None, "optuna._hypervolume.hssp"])
def test_other_missing_modules_keep_their_error(name: str | None) -> None:
    # Our own code's broken imports, a missing core dependency, or a file not found inside an installed zoo package
    # (Python names the top-level package when the package itself is absent) are not a missing extra
    with pytest.raises(ModuleNotFoundError), zoo_required():
        raise ModuleNotFoundError("No module", name=name)


def test_console_scripts_are_the_mains() -> None:
    # What ``sb3-offon-train``/``sb3-offon-enjoy`` run: the same ``main`` as ``python -m``, tested below
    scripts = {
        entry.name: entry.value for entry in entry_points(group="console_scripts") if entry.name.startswith("sb3-offon")
    }
    assert scripts == {"sb3-offon-train": "sb3_offon.train:main", "sb3-offon-enjoy": "sb3_offon.enjoy:main"}


def test_commands_without_the_zoo(tmp_path: Path) -> None:
    (tmp_path / "sitecustomize.py").write_text(HIDE_ZOO)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")]))}
    arguments = ["--algo", "offon_dqn", "--env", "CartPole-v1"]
    # Each main once, one through ``python -m`` and one through its console script as pip wrote it (two runs, not
    # four: most of each is the interpreter's start, with torch and SB3)
    script = Path(sysconfig.get_path("scripts")) / "sb3-offon-enjoy"
    assert script.is_file(), f"{script}: the package is not installed (pip install -e .)"
    commands = {"train": [sys.executable, "-m", "sb3_offon.train", *arguments], "enjoy": [str(script), *arguments]}
    processes = {
        name: subprocess.Popen(command, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for name, command in commands.items()
    }
    for name, process in processes.items():
        out, err = process.communicate(timeout=TIMEOUT)
        assert process.returncode == 1, (name, out, err)
        assert out == "", name
        lines = err.strip().splitlines()
        assert len(lines) == 1, (name, err)
        assert "'rl_zoo3'" in lines[0]
        assert INSTALL_HINT in lines[0]
