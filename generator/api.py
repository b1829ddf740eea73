"""Python entry point for generating a dataset (what `generate-scene` runs)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from generator.assets import load_manifest
from generator.ground_truth_refresh import refresh_ground_truth
from generator.job import resolve_asset_materials
from generator.pipeline import generate as _generate
from generator.presets import PRESET_DIR, load_preset
from generator.sampler import draw_spec
from generator.sampler_axes import parse_pins
from generator.spec import Overrides, SceneSpec, apply_overrides, load_spec_file, parse_spec


def resolve_spec(preset_or_spec: str | Path, overrides: Overrides | None = None) -> tuple[SceneSpec, str]:
    """A preset name or a YAML path, with overrides applied; also returns the source name."""
    path = Path(preset_or_spec)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        spec, source = load_spec_file(path), str(path)
    else:
        spec, source = load_preset(str(preset_or_spec)), str(PRESET_DIR / f"{preset_or_spec}.yaml")
    return apply_overrides(spec, overrides or Overrides()), source


def random_spec(seed: int, pins: Sequence[str] = (), overrides: Overrides | None = None) -> tuple[SceneSpec, str]:
    """The scene drawn from `seed` with `pins` (`AXIS=VALUE` items, docs/generator.md), with
    overrides applied; also returns the source name."""
    source = f"random scene {seed}"
    spec = parse_spec(draw_spec(seed, parse_pins(list(pins))), source)
    return apply_overrides(spec, overrides or Overrides()), source


def generate(preset_or_spec: str | Path, out: Path, *, force: bool = False, show_progress: bool = True,
             threads: int | None = None, bake_store: Path | None = None, **overrides: object) -> Path:
    """Generate a dataset; keyword overrides are the CLI's (frames, resolution, samples, ...);
    `bake_store` keeps the bake for other datasets of the same simulation (generator.bakes)."""
    spec, source = resolve_spec(preset_or_spec, Overrides(**overrides))  # type: ignore[arg-type]
    return _generate(spec, Path(out), source=source, force=force, show_progress=show_progress, threads=threads,
                     bake_store=bake_store)


def generate_random(seed: int, out: Path, *, pins: Sequence[str] = (), force: bool = False,
                    show_progress: bool = True, threads: int | None = None, bake_store: Path | None = None,
                    **overrides: object) -> Path:
    """Draw the scene of `seed` (with `pins`) and generate it; its scene.yaml regenerates it."""
    spec, source = random_spec(seed, pins, Overrides(**overrides))  # type: ignore[arg-type]
    return _generate(spec, Path(out), source=source, force=force, show_progress=show_progress, threads=threads,
                     bake_store=bake_store)


def refresh(spec: SceneSpec, source: str, dataset: Path, *, show_progress: bool = True, threads: int | None = None,
            bake_store: Path | None = None) -> Path:
    """Make the finished dataset at `dataset` the resolved `spec`'s by rendering only the ground truth
    it lacks (a pass such as rgb.shadowed, or clean passes at fewer samples); GeneratorError when it
    differs in anything else (generator.ground_truth_refresh)."""
    spec = resolve_asset_materials(spec, load_manifest(), source)
    return refresh_ground_truth(Path(dataset), spec, threads=threads, show_progress=show_progress,
                                bake_store=bake_store)
