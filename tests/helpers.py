"""Checks that several test modules share (pytest puts this folder on the import path; it collects no tests here)."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_offon.resume import Checkpoint, RunCheckpoint
from sb3_offon.train import main as train_main

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def assert_same_parameters(ours: BaseAlgorithm, reference: BaseAlgorithm) -> None:
    """Every tensor of the two policies is equal, bit for bit; a failure names the first one that differs."""
    for (name, ours_param), (_, reference_param) in zip(
        ours.policy.state_dict().items(), reference.policy.state_dict().items(), strict=True
    ):
        assert th.equal(ours_param, reference_param), name


def hide_minatar(monkeypatch: pytest.MonkeyPatch) -> None:
    """MinAtar absent for the test: its modules out of the cache, and its import made to fail as an uninstalled
    package's does."""
    for module in [name for name in sys.modules if name == "minatar" or name.startswith("minatar.")]:
        monkeypatch.delitem(sys.modules, module)
    monkeypatch.setitem(sys.modules, "minatar", None)


def load_script(name: str) -> ModuleType:
    """``scripts/<name>.py`` as a module (the scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(f"{name}_script", SCRIPTS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def interrupt_after_checkpoint(monkeypatch: pytest.MonkeyPatch, step: int) -> None:
    """Ctrl-C right after the first checkpoint at or after ``step`` (the zoo stops training and saves the model)."""
    save = RunCheckpoint.save

    def save_then_interrupt(self: RunCheckpoint) -> Checkpoint:
        checkpoint = save(self)
        if checkpoint.num_timesteps >= step:
            raise KeyboardInterrupt
        return checkpoint

    monkeypatch.setattr(RunCheckpoint, "save", save_then_interrupt)


def run_train(monkeypatch: pytest.MonkeyPatch, *arguments: str) -> int | str | None:
    """``python -m sb3_offon.train``'s ``main()`` on ``arguments``, in this process: its return value, or the status of
    the ``SystemExit`` it ends with."""
    monkeypatch.setattr(sys, "argv", ["sb3_offon.train", *arguments])
    try:
        return train_main()
    except SystemExit as exit_:
        return exit_.code
