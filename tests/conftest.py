"""Shared fixtures. `demo_dataset` runs the real generator (bpy + Mantaflow) once per test run."""
from __future__ import annotations

import os
from pathlib import Path

import pytest


@pytest.fixture(scope="package")  # tests/ is one package: one generation per test run
def demo_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The `demo` preset, generated for real. SMOKESEER_DEMO_DATASET reuses an existing one."""
    existing = os.environ.get("SMOKESEER_DEMO_DATASET")
    if existing:
        return Path(existing)
    from generator.api import generate

    return generate("demo", tmp_path_factory.mktemp("demo") / "dataset", show_progress=False)


@pytest.fixture(scope="package")  # tests/ is one package: one generation per test run
def demo_nosmoke_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The `demo` preset with its smoke sources removed (no domain, no bake), generated for real.
    SMOKESEER_DEMO_NOSMOKE_DATASET reuses an existing one."""
    existing = os.environ.get("SMOKESEER_DEMO_NOSMOKE_DATASET")
    if existing:
        return Path(existing)
    import yaml

    from generator.api import generate
    from generator.presets import preset_path

    spec = yaml.safe_load(preset_path("demo").read_text())
    spec.update(name="demo_nosmoke", sources=[])
    root = tmp_path_factory.mktemp("demo_nosmoke")
    (root / "demo_nosmoke.yaml").write_text(yaml.safe_dump(spec))
    return generate(root / "demo_nosmoke.yaml", root / "dataset", show_progress=False)
