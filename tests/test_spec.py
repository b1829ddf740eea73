"""Scene spec validation: every bad input names its file and field."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from generator.errors import SpecError
from generator.presets import PRESET_DIR, list_presets, load_preset
from generator.spec import Overrides, apply_overrides, load_spec_file, parse_passes, parse_spec


def demo_dict() -> dict:
    return yaml.safe_load((PRESET_DIR / "demo.yaml").read_text())


def test_presets_load_and_hash_is_stable() -> None:
    assert "demo" in list_presets()
    a, b = load_preset("demo"), load_preset("demo")
    assert a == b and a.sha256() == b.sha256()
    assert a.has_smoke and not a.has_fire


@pytest.mark.parametrize("name", list_presets())
def test_written_spec_loads_back_to_an_equal_spec(name: str) -> None:
    spec = load_preset(name)
    back = parse_spec(yaml.safe_load(yaml.safe_dump(spec.to_dict(), sort_keys=False)), "scene.yaml")
    assert back == spec and back.sha256() == spec.sha256()


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["rig"]["rgb"].update(width=-64), "rig.rgb.width"),
    (lambda d: d.update(frames=0), "frames"),
    (lambda d: d["objects"][0].update(material="nope"), "objects[0].material"),
    (lambda d: d["sources"][0].update(type="plasma"), "sources[0].type"),
    (lambda d: d["materials"]["skin"].update(emissivity=1.5), "materials.skin.emissivity"),
    (lambda d: d["materials"]["skin"].update(temperature_k=-3), "materials.skin.temperature_k"),
    (lambda d: d["sim"].update(resolution="big"), "sim.resolution"),
    (lambda d: d["sim"].update(vorticty=0.1), "sim.vorticty"),
    (lambda d: d["rig"]["trajectory"].update(center=[0, 0]), "rig.trajectory.center"),
    (lambda d: d["rig"]["trajectory"].update(radius=float("nan")), "rig.trajectory.radius"),
    (lambda d: d.update(passes=["rgb.colour"]), "passes"),
    (lambda d: d["smoke"].update(density_scale=-0.5), "smoke.density_scale"),
    (lambda d: d["smoke"].update(density_scale=float("inf")), "smoke.density_scale"),
    (lambda d: d["smoke"].update(density_scale="thick"), "smoke.density_scale"),
    (lambda d: d["rig"]["rgb"].update(clean_samples=0), "rig.rgb.clean_samples"),
])
def test_bad_fields_name_file_and_field(mutate, field: str) -> None:
    data = demo_dict()
    mutate(data)
    with pytest.raises(SpecError) as err:
        parse_spec(data, "scene.yaml")
    assert err.value.field == field
    assert str(err.value).startswith(f"scene.yaml: {field}: ")


def test_malformed_yaml_reports_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nobjects: [\n  - asset: box\n")
    with pytest.raises(SpecError, match=r"bad.yaml: malformed YAML at line \d+"):
        load_spec_file(bad)


def test_overrides_apply_and_reject_bad_values() -> None:
    spec = apply_overrides(load_preset("demo"), Overrides(frames=3, resolution=(40, 30), seed=7,
                                                          passes="rgb.smoky,thermal"))
    assert (spec.frames, spec.rig.rgb.width, spec.rig.rgb.height, spec.seed) == (3, 40, 30, 7)
    assert spec.passes == {"rgb": ("smoky",), "thermal": ("smoky", "clean", "depth", "smoke_alpha")}
    for bad in (Overrides(frames=0), Overrides(resolution=(-1, 5)), Overrides(sim_resolution=2)):
        with pytest.raises(SpecError, match="command line"):
            apply_overrides(load_preset("demo"), bad)


def test_density_scale_is_a_spec_field_and_an_override() -> None:
    demo = load_preset("demo")
    assert demo.smoke.density_scale == 1.0
    scaled = apply_overrides(demo, Overrides(density_scale=2.5))
    assert scaled.smoke.density_scale == 2.5 and scaled.sha256() != demo.sha256()
    assert apply_overrides(demo, Overrides(density_scale=0.0)).smoke.density_scale == 0.0
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(SpecError) as err:
            apply_overrides(demo, Overrides(density_scale=bad))
        assert str(err.value).startswith("command line: --density-scale: must be a finite number in [0, ")


def test_parse_passes_orders_and_dedupes() -> None:
    assert parse_passes("thermal.depth,rgb,thermal.depth", "x") == {
        "rgb": ("smoky", "clean", "shadowed", "depth", "smoke_alpha"), "thermal": ("depth",)}
    assert parse_passes("thermal", "x") == {"thermal": ("smoky", "clean", "depth", "smoke_alpha")}


def test_shadowed_is_an_rgb_pass_only() -> None:
    """The thermal render has no lights, so the smoke casts no shadow there: one line, naming the item."""
    with pytest.raises(SpecError, match="unknown pass in 'thermal.shadowed'; thermal has smoky, clean, depth"):
        parse_passes("rgb.shadowed,thermal.shadowed", "x")


def test_parser_is_driven_by_field_metadata() -> None:
    """Defaults and ranges live once, on the dataclass fields; the parser restates none of them."""
    import dataclasses

    from generator import spec as spec_mod

    specially_read = {("MaterialSpec", "name"), ("ObjectSpec", "name"), ("ObjectSpec", "asset"),
                      ("ObjectSpec", "material"), ("SceneSpec", "sources"), ("SceneSpec", "objects"),
                      ("SceneSpec", "materials"), ("SceneSpec", "rig"), ("SceneSpec", "passes"),
                      ("RigSpec", "trajectory"), ("RigSpec", "rgb"), ("RigSpec", "thermal")}
    classes = [spec_mod.TextureSpec, spec_mod.MaterialSpec, spec_mod.ObjectSpec, spec_mod.SourceSpec,
               spec_mod.SimSpec, spec_mod.SmokeSpec, spec_mod.LightSpec, spec_mod.TrajectorySpec,
               spec_mod.CameraSpec, spec_mod.ThermalCameraSpec, spec_mod.RigSpec, spec_mod.SceneSpec]
    for cls in classes:
        for fld in dataclasses.fields(cls):
            assert fld.metadata.get("spec") or (cls.__name__, fld.name) in specially_read, f"{cls.__name__}.{fld.name}"
    minimal = parse_spec({"name": "bare", "sources": [{"position": [0, 0, 0]}]}, "bare.yaml")
    assert minimal.sim == spec_mod.SimSpec() and minimal.smoke == spec_mod.SmokeSpec()
    assert minimal.lights == spec_mod.LightSpec() and minimal.sources[0] == spec_mod.SourceSpec(position=(0, 0, 0))
    assert minimal.rig.rgb == spec_mod.RGB_CAMERA and minimal.rig.thermal == spec_mod.THERMAL_CAMERA
    # A range in the metadata is what the parser enforces.
    limit = next(f for f in dataclasses.fields(spec_mod.SimSpec) if f.name == "resolution").metadata["maximum"]
    with pytest.raises(SpecError, match=rf"bad.yaml: sim.resolution: must be at most {limit}, got {limit + 1}"):
        parse_spec({"name": "x", "sim": {"resolution": limit + 1}}, "bad.yaml")


def test_render_budget_names_the_camera_field() -> None:
    """A frame that cannot fit in memory is refused where the spec is read, naming the camera;
    the largest frame the camera fields allow (16384 x 16384 RGB) is exactly at the limit."""
    from generator import spec as spec_mod
    from generator.spec import MAX_RENDER_BYTES, BYTES_PER_RENDER_PIXEL

    assert 16384 * 16384 * BYTES_PER_RENDER_PIXEL == MAX_RENDER_BYTES
    with pytest.raises(SpecError, match=r"bad.yaml: rig.thermal: 16384x16384 \(x2 supersampled\) needs about 64 GiB"):
        parse_spec({"name": "x", "rig": {"thermal": {"width": 16384, "height": 16384}}}, "bad.yaml")
    big = parse_spec({"name": "x", "frames": 2, "rig": {"rgb": {"width": 16384, "height": 16384}}}, "ok.yaml")
    assert big.rig.rgb.width == 16384
    with pytest.raises(SpecError, match=r"many.yaml: rig.rgb: 1.2e\+12 pixel-samples in all \(16 rgb frames of "
                                         r"16384x16384 at 64 samples, 64 for clean and shadowed, 5 passes\)"):
        parse_spec({"name": "x", "frames": 16, "rig": {"rgb": {"width": 16384, "height": 16384, "samples": 64,
                                                             "clean_samples": 64}}}, "many.yaml")
    # The clean and shadowed passes count at their own samples.
    with pytest.raises(SpecError, match=r"clean.yaml: rig.rgb: 2.2e\+12 pixel-samples in all"):
        parse_spec({"name": "x", "frames": 16, "rig": {"rgb": {"width": 16384, "height": 16384, "samples": 64,
                                                             "clean_samples": 256}}}, "clean.yaml")
    # The shadowed pass counts its test views alone (frames 2, 6 and 10 of 13), as it is rendered:
    # 13 x 4 + 3 frame-passes fit in 10^12 where 13 x 5 would not.
    few = parse_spec({"name": "x", "frames": 13, "rig": {"rgb": {"width": 16384, "height": 16384, "samples": 64,
                                                               "clean_samples": 64}}}, "few.yaml")
    assert few.test_frames() == {2, 6, 10}
    assert 16384 ** 2 * 64 * 13 * 5 > spec_mod.MAX_PIXEL_SAMPLES
