"""Shared fixtures. ``tiny_dataset_path`` generates the ``tiny`` preset once per test session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering backend; must precede any robosuite import


@pytest.fixture(scope="session")
def tiny_dataset_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ``tiny`` dataset (tool embodiment, 5 demos x 3 trials, H = 40) in a session temp dir."""
    from dcm.data.generate import ensure_dataset

    path = tmp_path_factory.mktemp("data") / "tiny.h5"
    return ensure_dataset("tiny", path, overrides=["workers=1", "progress=false"])
