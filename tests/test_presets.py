"""The ten benchmark presets: they parse, reference real assets, span the paper's densities,
have fire and strong motion where claimed, unsynchronised rigs, and stand on their terrain."""
from __future__ import annotations

import numpy as np
import pytest

from generator.assets import load_manifest
from generator.benchmark_cli import extinction_scale
from generator.job import resolve_asset_materials
from generator.meshgen import RECIPES as MESH_RECIPES
from generator.meshgen import sample_terrain
from generator.presets import list_presets, load_preset
from generator.profiles import (
    BENCHMARK_SCENES,
    OBJECT_LEVEL,
    PROFILES,
    strong_motion,
)
from generator.rig import rgb_frames, thermal_frames, timeline
from generator.spec import apply_overrides

# The paper's per-scene smoke densities (SmokeSeer, synthetic benchmark), the reference our
# analogue scenes must reproduce.
PAPER_DENSITY = {"caterpillar": 0.4, "ficus": 0.75, "mars": 0.3, "room": 1.0, "musclecar": 0.7, "hotdog": 1.0,
                 "forest": 0.5, "chair": 0.7, "lego": 0.65, "house": 0.2}


@pytest.fixture(scope="module")
def specs() -> dict:
    return {name: load_preset(name) for name in BENCHMARK_SCENES}


@pytest.fixture(scope="module")
def manifest():
    return load_manifest()


def test_all_ten_presets_exist_and_parse(specs: dict) -> None:
    assert set(BENCHMARK_SCENES) <= set(list_presets())
    assert len(specs) == 10
    for name, spec in specs.items():
        assert spec.name == name
        assert spec.has_smoke


def test_every_asset_and_material_resolves(specs: dict, manifest) -> None:
    for name, spec in specs.items():
        resolved = resolve_asset_materials(spec, manifest, name)
        for obj in resolved.objects:
            assert obj.asset in manifest.assets, f"{name}: {obj.asset}"
            assert obj.material in resolved.materials, f"{name}: {obj.name}"


def test_densities_are_the_papers(specs: dict) -> None:
    densities = {name: spec.smoke.density for name, spec in specs.items()}
    for name, analogue in BENCHMARK_SCENES.items():
        assert densities[name] == pytest.approx(PAPER_DENSITY[analogue])
    assert min(densities.values()) == pytest.approx(0.2)
    assert max(densities.values()) == pytest.approx(1.0)


def test_extinction_calibration_inverts_beer_lambert() -> None:
    """Opacity 1-exp(-tau): scaling tau by k is what `extinction_scale` must recover."""
    assert extinction_scale(np.full((2, 4, 4), 0.5), 0.02, 0.75) == pytest.approx(2.0, rel=1e-6)
    rng = np.random.default_rng(1)
    tau = rng.exponential(0.4, (3, 20, 20))
    alphas = -np.expm1(-tau)
    inside = alphas > 0.02
    target = float(np.mean(-np.expm1(-3.0 * tau[inside])))
    assert extinction_scale(alphas, 0.02, target) == pytest.approx(3.0, rel=1e-4)
    assert np.isnan(extinction_scale(np.zeros((1, 3, 3)), 0.02, 0.5))


def test_fire_and_strong_motion_counts(specs: dict) -> None:
    fire = [n for n, s in specs.items() if s.has_fire]
    motion = [n for n, s in specs.items() if strong_motion(s)]
    assert len(fire) >= 2, fire
    assert len(motion) >= 2, motion
    for name in fire:
        spec = specs[name]
        assert max(s.temperature_k for s in spec.sources if s.kind != "smoke") >= 900.0


def test_frames_and_unsynchronised_rigs(specs: dict) -> None:
    for name, spec in specs.items():
        assert spec.frames == 150, name
        rgb, thermal = spec.rig.rgb, spec.rig.thermal
        assert thermal.fps != rgb.fps and thermal.time_offset_s > 0, name
        short = apply_overrides(spec, PROFILES["bench"].overrides)
        line = timeline(short)
        rgb_t = {f.timestamp_s for f in rgb_frames(short, line)}
        thermal_t = [f.timestamp_s for f in thermal_frames(short, line)]
        assert len(thermal_t) >= 2
        assert sum(t in rgb_t for t in thermal_t) < len(thermal_t), f"{name}: thermal frames all coincide with RGB"


def test_orbit_and_flyover_split(specs: dict) -> None:
    for name, spec in specs.items():
        expected = "orbit" if name in OBJECT_LEVEL else "flyover"
        assert spec.rig.trajectory.kind == expected, name
    assert len(OBJECT_LEVEL) == 5


def test_orbit_cameras_stay_outside_the_smoke_domain(specs: dict) -> None:
    """A drone inside the plume would see nothing but smoke; object scenes look at it from outside."""
    for name in OBJECT_LEVEL:
        spec = apply_overrides(specs[name], PROFILES["bench"].overrides)
        lo = np.asarray(spec.sim.center) - np.asarray(spec.sim.size) / 2
        hi = np.asarray(spec.sim.center) + np.asarray(spec.sim.size) / 2
        for frame in rgb_frames(spec, timeline(spec)):
            position = frame.c2w[:3, 3]
            assert not np.all((position > lo) & (position < hi)), f"{name}: camera inside the smoke domain"


def test_thermal_structure_is_plausible(specs: dict, manifest) -> None:
    """Every scene has a hot spot well above ambient and a spread of surface temperatures."""
    for name, spec in specs.items():
        resolved = resolve_asset_materials(spec, manifest, name)
        used = {o.material for o in resolved.objects}
        temps = [resolved.materials[m].temperature_k for m in used]
        ambient = spec.lights.ambient_temperature_k
        assert max(temps) >= ambient + 10.0, name
        assert max(temps) - min(temps) >= 10.0, name
        assert spec.lights.sky_temperature_k < ambient - 20.0, name


GROUNDED_ASSETS = ("rock_a", "rock_b", "rock_c", "trunk", "person", "wheel", "rover_body", "fries")


@pytest.mark.parametrize("scene, terrain", [("forest", "forest_terrain"), ("rover", "mars_terrain")])
def test_objects_stand_on_the_generated_terrain(specs: dict, scene: str, terrain: str) -> None:
    """Things that stand on the ground (rocks, trunks, people, wheels) touch the heightfield:
    not floating, not buried (within 0.5 m of it at their origin)."""
    recipe = MESH_RECIPES[terrain]
    objects = [o for o in specs[scene].objects if o.asset in GROUNDED_ASSETS]
    assert len(objects) >= 5
    xy = np.array([o.location[:2] for o in objects])
    ground = sample_terrain(recipe, xy[:, 0], xy[:, 1])
    for obj, h in zip(objects, ground):
        assert abs(obj.location[2] - h) <= 0.5, f"{scene}: {obj.name} at z={obj.location[2]:.2f}, ground {h:.2f}"


def test_profiles_shrink_and_grow_the_presets(specs: dict) -> None:
    for name, spec in specs.items():
        bench = apply_overrides(spec, PROFILES["bench"].overrides)
        paper = apply_overrides(spec, PROFILES["paper"].overrides)
        assert bench.frames < spec.frames == paper.frames == 150
        assert bench.rig.rgb.width < spec.rig.rgb.width < paper.rig.rgb.width, name
        assert bench.rig.thermal.width < spec.rig.thermal.width < paper.rig.thermal.width, name
        assert bench.sim.resolution < spec.sim.resolution < paper.sim.resolution, name


@pytest.mark.slow
@pytest.mark.blender
def test_forest_generates_for_real_at_tiny_size(tmp_path) -> None:
    """Terrain and rock files, 46 recipe objects, fire and wind through the whole pipeline; the
    smoke is denser in RGB than in LWIR (thermal sees through it)."""
    from generator.api import generate
    from contracts.dataset_format import validate_dataset

    out = generate("forest", tmp_path / "forest", show_progress=False, frames=2, resolution=(32, 24),
                   thermal_resolution=(16, 12), sim_resolution=16, samples=4)
    meta = validate_dataset(out)
    stats = meta["stats"]
    assert meta["smoke"]["fire"] and meta["scene"] == "forest"
    assert stats["rgb_mean_smoke_alpha"] > 0.01
    assert stats["rgb_mean_smoke_alpha"] > 2 * stats["thermal_mean_smoke_alpha"]
