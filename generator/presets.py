"""Built-in scene presets: YAML specs shipped inside the package."""
from __future__ import annotations

from pathlib import Path

from generator.errors import SpecError
from generator.spec import SceneSpec, load_spec_file

PRESET_DIR = Path(__file__).resolve().parent / "presets"


def list_presets() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


def preset_path(name: str) -> Path:
    path = PRESET_DIR / f"{name}.yaml"
    if not path.is_file():
        raise SpecError("--preset", name, f"unknown preset; available: {', '.join(list_presets())}")
    return path


def load_preset(name: str) -> SceneSpec:
    return load_spec_file(preset_path(name))
