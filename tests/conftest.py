"""Shared fixtures. `demo_dataset` runs the real generator (bpy + Mantaflow) once per session."""
from __future__ import annotations

import os
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def demo_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The `demo` preset, generated for real. SMOKESEER_DEMO_DATASET reuses an existing one."""
    existing = os.environ.get("SMOKESEER_DEMO_DATASET")
    if existing:
        return Path(existing)
    from generator.api import generate

    return generate("demo", tmp_path_factory.mktemp("demo") / "dataset", show_progress=False)
