"""
The libraries' own tests, run with this package's drop-ins: Stable-Baselines3's tests of DQN with OffOnDQN in place of
DQN, and sb3-contrib's tests of QR-DQN with OffOnQRDQN, and with ``sb3_offon.qrdqn.QRDQN``, in place of QRDQN.

Their test code is not part of this repository: the test downloads the sdist of the installed library from PyPI
(``pip download``), keeps its ``tests/`` folder and its pytest configuration in a cache folder, and runs the test
files that exercise the original algorithm in a pytest subprocess with the plugin
``tests/sb3_suite/sb3_offon_plugin.py``, which swaps the original for the drop-in and selects the tests that exercise
it (see its docstring: one SB3 test, which reads the tensorboard run folder by DQN's run name, runs with that run name).

- Select them with ``pytest -m sb3_suite``; leave them out with ``-m "not sb3_suite"``.
- The cache is ``$SB3_OFFON_CACHE`` if set, else ``~/.cache/sb3-offon``; a cached copy is reused.
- Without network (or without PyPI) the tests fail: set ``SB3_OFFON_SKIP_SB3_SUITE=1`` to skip them instead.
- By hand: ``python tests/test_sb3_suite.py [OffOnDQN|OffOnQRDQN|QRDQN] [pytest args]`` runs the same subprocess,
  printing its output.
"""

import importlib.util
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import pytest
import sb3_contrib
import stable_baselines3

PLUGIN_DIR = Path(__file__).resolve().parent / "sb3_suite"

# SB3's test files that exercise DQN (``grep -l DQN tests/*.py`` on SB3 2.9), each with the modules it imports that
# are not dependencies of this project: a file whose modules are missing is left out (and said so), not failed.
SB3_TEST_FILES: dict[str, tuple[str, ...]] = {
    "test_callbacks.py": (),
    "test_cnn.py": (),
    "test_custom_policy.py": (),
    "test_deterministic.py": (),
    "test_dict_env.py": (),
    "test_her.py": (),
    "test_identity.py": (),
    "test_logger.py": (),
    "test_n_step_replay.py": (),
    "test_predict.py": (),
    "test_run.py": (),
    "test_save_load.py": (),
    "test_spaces.py": (),
    "test_train_eval_mode.py": (),
    # Imports ale_py at module level, for its Atari tests; its DQN test is test_policy_is_vectorized_obs
    "test_utils.py": ("ale_py",),
}
# sb3-contrib's test files that exercise QRDQN (``grep -l QRDQN tests/*.py`` on sb3-contrib 2.9)
CONTRIB_TEST_FILES: dict[str, tuple[str, ...]] = {
    name: ()
    for name in (
        "test_cnn.py",
        "test_deterministic.py",
        "test_dict_env.py",
        "test_identity.py",
        "test_run.py",
        "test_save_load.py",
        "test_train_eval_mode.py",
    )
}


@dataclass(frozen=True)
class Suite:
    """A library's tests of an algorithm, run with a drop-in in its place (``SB3_OFFON_SWAP`` of the plugin)."""

    distribution: str  # on PyPI
    version: str  # the installed one's
    test_files: dict[str, tuple[str, ...]]
    swap: str
    # The run must have passed at least this many tests, so that it cannot pass by collecting nothing
    min_passed: int


SUITES = {
    # SB3 2.9.2: 68 passed, 6 skipped (67 passed without ale_py)
    "OffOnDQN": Suite("stable-baselines3", stable_baselines3.__version__, SB3_TEST_FILES, "OffOnDQN", 60),
    # sb3-contrib 2.9.2: 32 passed, 1 skipped, for each drop-in
    "OffOnQRDQN": Suite("sb3-contrib", sb3_contrib.__version__, CONTRIB_TEST_FILES, "OffOnQRDQN", 28),
    "QRDQN": Suite("sb3-contrib", sb3_contrib.__version__, CONTRIB_TEST_FILES, "QRDQN", 28),
}

SUBPROCESS_TIMEOUT_S = 1800


def cache_root() -> Path:
    return Path(os.environ.get("SB3_OFFON_CACHE", Path.home() / ".cache" / "sb3-offon"))


def fetch_tests(distribution: str, version: str) -> Path:
    """
    The folder holding the ``tests/`` and ``pyproject.toml`` (its pytest configuration) of ``distribution`` ``version``
    (``stable-baselines3``, ``sb3-contrib``), downloaded from PyPI once and cached.

    :raises RuntimeError: where the sdist cannot be downloaded or has no tests
    """
    sdist_name = distribution.replace("-", "_")
    target = cache_root() / f"{sdist_name}-{version}"
    if (target / "tests").is_dir() and (target / "pyproject.toml").is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        download = subprocess.run(
            [
                sys.executable,
                *("-m", "pip", "download", "--no-binary", ":all:", "--no-deps", "--disable-pip-version-check"),
                *(f"{distribution}=={version}", "-d", tmp),
            ],
            capture_output=True,
            text=True,
            timeout=600,
        )
        sdists = list(Path(tmp).glob(f"{sdist_name}-*.tar.gz"))
        if download.returncode != 0 or len(sdists) != 1:
            raise RuntimeError(
                f"could not download the sdist of {distribution}=={version} (exit {download.returncode}):\n"
                f"{download.stdout[-3000:]}\n{download.stderr[-3000:]}"
            )
        extracted = Path(tmp) / "extracted"
        prefix = f"{sdists[0].name.removesuffix('.tar.gz')}/"
        with tarfile.open(sdists[0]) as archive:
            members = [
                member
                for member in archive.getmembers()
                if member.name.startswith(f"{prefix}tests/") or member.name == f"{prefix}pyproject.toml"
            ]
            if hasattr(tarfile, "data_filter"):
                archive.extractall(extracted, members=members, filter="data")
            else:  # Python < 3.10.12 / 3.11.4
                archive.extractall(extracted, members=members)
        source = extracted / prefix
        if not (source / "tests").is_dir() or not (source / "pyproject.toml").is_file():
            raise RuntimeError(f"{sdists[0].name} has no tests/ folder or no pyproject.toml")
        try:
            source.rename(target)
        except OSError:
            # Another process filled the cache in the meantime
            if not (target / "tests").is_dir():
                shutil.rmtree(target, ignore_errors=True)
                source.rename(target)
    return target


def missing_modules(modules: tuple[str, ...]) -> list[str]:
    return [module for module in modules if importlib.util.find_spec(module) is None]


def suite_pytest_command(suite: Suite, tests_dir: Path, extra_args: list[str] = ()) -> tuple[list[str], list[str]]:
    """The pytest command line over the suite's test files, and the files left out (with the modules they miss)."""
    files, left_out = [], []
    for name, modules in suite.test_files.items():
        path = tests_dir / "tests" / name
        missing = missing_modules(modules)
        if missing:
            left_out.append(f"{name} (needs {', '.join(missing)})")
        elif path.is_file():
            files.append(str(path))
        else:
            left_out.append(f"{name} (not in this version's tests)")
    command = [
        sys.executable,
        *("-m", "pytest", "-c", str(tests_dir / "pyproject.toml"), "--rootdir", str(tests_dir)),
        *("-p", "sb3_offon_plugin", "--swapped-only", "-p", "no:cacheprovider", "-q", "-rfEs"),
        *extra_args,
        *files,
    ]
    return command, left_out


def suite_subprocess_env(suite: Suite) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PLUGIN_DIR), env.get("PYTHONPATH")]))
    env["SB3_OFFON_SWAP"] = suite.swap
    # Our own pytest options (say -W error or --strict-markers through PYTEST_ADDOPTS) are not the library's
    env.pop("PYTEST_ADDOPTS", None)
    # One torch/BLAS thread: the tests use small networks, and on a busy 2-core machine the default threads fight
    # over the cores (measured: SB3's test_her.py::test_performance_her 208 s with the default, 8 s with one thread)
    for variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(variable, "1")
    return env


@pytest.mark.slow
@pytest.mark.sb3_suite
@pytest.mark.parametrize("drop_in", list(SUITES))
def test_the_libraries_tests_pass_with_the_drop_in(drop_in: str, tmp_path: Path) -> None:
    if os.environ.get("SB3_OFFON_SKIP_SB3_SUITE") == "1":
        pytest.skip("SB3_OFFON_SKIP_SB3_SUITE=1")
    suite = SUITES[drop_in]
    # No skip on a failed download: the suite is a requirement, set SB3_OFFON_SKIP_SB3_SUITE=1 to go without it
    tests_dir = fetch_tests(suite.distribution, suite.version)

    report = tmp_path / "report.xml"
    command, left_out = suite_pytest_command(suite, tests_dir, [f"--junitxml={report}"])
    if left_out:
        print(f"{suite.distribution} test files left out: {'; '.join(left_out)}")
    result = subprocess.run(
        command,
        cwd=tmp_path,  # some of the tests write to the working directory
        env=suite_subprocess_env(suite),
        capture_output=True,
        text=True,
        timeout=SUBPROCESS_TIMEOUT_S,
    )
    output = f"$ {' '.join(command)}\n{result.stdout[-20000:]}\n{result.stderr[-5000:]}"
    exit_code = result.returncode
    assert exit_code == 0, f"{suite.distribution}'s tests failed with {drop_in} (exit {exit_code}):\n{output}"

    junit = ET.parse(report).getroot()
    junit = junit if junit.tag == "testsuite" else junit.find("testsuite")
    counts = {key: int(junit.get(key, 0)) for key in ("tests", "failures", "errors", "skipped")}
    passed = counts["tests"] - counts["failures"] - counts["errors"] - counts["skipped"]
    print(f"{suite.distribution} {suite.version} tests with {drop_in}: {passed} passed, {counts}")
    assert counts["failures"] == counts["errors"] == 0, output
    assert passed >= suite.min_passed, f"only {passed} tests passed, expected at least {suite.min_passed}:\n{output}"


if __name__ == "__main__":
    chosen = SUITES[sys.argv[1]] if len(sys.argv) > 1 and sys.argv[1] in SUITES else SUITES["OffOnDQN"]
    pytest_args = sys.argv[2:] if len(sys.argv) > 1 and sys.argv[1] in SUITES else sys.argv[1:]
    suite_command, suite_left_out = suite_pytest_command(chosen, fetch_tests(chosen.distribution, chosen.version), pytest_args)
    if suite_left_out:
        print(f"{chosen.distribution} test files left out: {'; '.join(suite_left_out)}", file=sys.stderr)
    sys.exit(subprocess.run(suite_command, env=suite_subprocess_env(chosen)).returncode)
