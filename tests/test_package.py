"""The package as it is published: one version everywhere, the license, the README's size, and the wheel on its own."""

import re
import shutil
import subprocess
import sys
from importlib.metadata import metadata
from importlib.metadata import version as installed_version
from pathlib import Path

import pytest

import sb3_offon

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT = 600
# The README fits on a few screens; the rest is in docs/
README_MAX_BYTES = 10_000
# Its first screen says what the package offers and which algorithm to pick
FIRST_SCREEN_LINES = 60


def test_version_is_single_sourced() -> None:
    written = (ROOT / "sb3_offon" / "version.txt").read_text().strip()
    assert re.fullmatch(r"\d+\.\d+\.\d+", written), written
    assert sb3_offon.__version__ == written
    # Installed metadata (setuptools reads the same file); after a bump, reinstall: pip install -e .
    assert installed_version("sb3-offon") == written
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert 'dynamic = ["version"]' in pyproject and "\nversion = " not in pyproject.split("[tool.setuptools.dynamic]")[0]
    assert 'version = {file = "sb3_offon/version.txt"}' in pyproject
    assert '"version.txt"' in pyproject.split("[tool.setuptools.package-data]")[1]
    # The changelog has the version's heading, and the documentation reads the same file
    assert re.search(rf"^## \[{re.escape(written)}\]", (ROOT / "CHANGELOG.md").read_text(), flags=re.MULTILINE)
    assert 'ROOT / "sb3_offon" / "version.txt"' in (ROOT / "docs" / "conf.py").read_text()


def test_license_and_metadata() -> None:
    assert (ROOT / "LICENSE").read_text().startswith("MIT License\n")
    # The installed metadata, as a wheel built from pyproject.toml carries it
    meta = metadata("sb3-offon")
    assert meta["License-Expression"] == "MIT"
    assert meta["Keywords"] and meta.get_all("Classifier")
    # An SPDX license expression excludes license classifiers
    assert not any(classifier.startswith("License ::") for classifier in meta.get_all("Classifier"))
    # The docs extra is part of "all", so that CI builds the documentation
    assert 'all = ["sb3-offon[zoo,bench,tests,docs,minatar,atari]"]' in (ROOT / "pyproject.toml").read_text()


def test_readme_is_short_and_opens_with_what_the_package_is() -> None:
    readme = (ROOT / "README.md").read_bytes()
    assert len(readme) <= README_MAX_BYTES, len(readme)
    paragraphs = readme.decode().split("\n\n")
    assert paragraphs[0] == "# sb3-offon"
    assert paragraphs[1].startswith("sb3-offon is ")
    first_screen = readme.decode().splitlines()[:FIRST_SCREEN_LINES]
    assert "What it offers:" in first_screen and "## Which algorithm to pick" in first_screen
    # Its links into the documentation lead to pages that exist
    for target in re.findall(r"\]\(((?:docs/)?[\w./-]+\.md)\)", readme.decode()):
        assert (ROOT / target).is_file(), target


def test_mypy_reads_the_same_with_and_without_the_minatar_extra() -> None:
    # `mypy` passes with the README's first extras only (`.[zoo]`, no MinAtar) as with `.[all]` (CI): MinAtar is among
    # the untyped packages whose missing imports mypy ignores, so no import of it needs an ignore comment of its own
    tomllib = pytest.importorskip("tomllib")
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]
    ignored = {
        module for override in config["overrides"] if override.get("ignore_missing_imports") for module in override["module"]
    }
    assert "minatar.*" in ignored
    for path in (ROOT / "sb3_offon").rglob("*.py"):
        for line in path.read_text().splitlines():
            if re.match(r"\s*(from|import) minatar\b", line):
                assert "type: ignore" not in line, f"{path}: {line.strip()}"


@pytest.mark.slow
def test_wheel_installed_apart_from_the_source_trains(tmp_path: Path) -> None:
    # The wheel is built from a copy of what it is made of (no build/ or egg-info left in the checkout) and installed
    # alone into a folder of its own; its dependencies are this environment's
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, source / name)
    shutil.copytree(ROOT / "sb3_offon", source / "sb3_offon", ignore=shutil.ignore_patterns("__pycache__"))
    wheels, site = tmp_path / "wheels", tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "-q", "--disable-pip-version-check"]
    commands = [
        [*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", str(wheels), str(source)],
    ]
    for command in commands:
        result = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT)
        assert result.returncode == 0, result.stderr[-3000:]
    (wheel,) = wheels.glob("sb3_offon-*.whl")
    assert wheel.name == f"sb3_offon-{sb3_offon.__version__}-py3-none-any.whl"
    for command in (
        [*pip, "install", "--no-deps", "--no-index", "--target", str(site), str(wheel)],
        [sys.executable, "-m", "twine", "check", "--strict", str(wheel)],
    ):
        result = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT)
        assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    run = tmp_path / "run"
    run.mkdir()
    env = {"PYTHONPATH": str(site), "PATH": str(Path(sys.executable).parent), "HOME": str(tmp_path)}
    check = "import sb3_offon; print(sb3_offon.__file__); print(sb3_offon.__version__)"
    result = subprocess.run([sys.executable, "-c", check], cwd=run, env=env, capture_output=True, text=True, timeout=TIMEOUT)
    assert result.returncode == 0, result.stderr
    path, version = result.stdout.split()
    assert Path(path).is_relative_to(site) and version == sb3_offon.__version__
    train = ["--algo", "offon_dqn", "--env", "CartPole-v1", "-n", "300", "--seed", "0", "-f", "logs", "--num-threads", "1"]
    short = ["--eval-freq", "-1", "--hyperparams", "learning_starts:100", "train_freq:64", "gradient_steps:4"]
    result = subprocess.run(
        [sys.executable, "-m", "sb3_offon.train", *train, *short],
        cwd=run,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    # The bundled settings were read from the installed wheel, and the model was saved
    assert f"Loading hyperparameters from: {site}" in result.stdout
    assert (run / "logs" / "offon_dqn" / "CartPole-v1_1" / "CartPole-v1.zip").is_file()
