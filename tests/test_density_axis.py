"""Issue 49's density axis: one bake rendered at several smoke densities k, its opacity
1 - (1 - alpha)^k, k = 0 the smoke-free scene, and the bake reused rather than simulated again."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from contracts.dataset_format import density_scale
from contracts.errors import DatasetError
from contracts.imageio import read_exr_channel, read_png
from generator.assets import load_manifest
from generator.bakes import bake_key
from generator.job import make_job, make_plan, resolve_asset_materials
from generator.postprocess import psnr_u8
from generator.presets import PRESET_DIR, load_preset


def test_bake_key_ignores_what_only_the_renders_read(tmp_path: Path) -> None:
    manifest = load_manifest()
    demo = resolve_asset_materials(load_preset("demo"), manifest, "demo.yaml")
    demo_plan = make_plan(demo)

    def key(spec, code: str = "code", same_plan: bool = True) -> str:
        plan = demo_plan if same_plan else make_plan(spec)  # Mie optics make a plan slow; most cases share it
        return bake_key(make_job(spec, plan, manifest, "demo.yaml", tmp_path, 1), code)

    rig = demo.rig
    base = key(demo)
    for spec in (replace(demo, smoke=replace(demo.smoke, density_scale=2.0)),
                 replace(demo, smoke=replace(demo.smoke, density_scale=0.0)),
                 replace(demo, seed=5)):
        assert key(spec) == base
    smaller = replace(demo, rig=replace(rig, rgb=replace(rig.rgb, width=32, height=24, samples=4, clean_samples=8)),
                      passes={"rgb": ("smoky",)})
    assert key(smaller, same_plan=False) == base
    for spec in (replace(demo, sim=replace(demo.sim, resolution=16)),
                 replace(demo, sources=(replace(demo.sources[0], rate=0.5),)),
                 replace(demo, smoke=replace(demo.smoke, extinction_per_m=4.0))):  # the smoke material is saved
        assert key(spec) != base
    assert key(replace(demo, frames=demo.frames + 4), same_plan=False) != base  # a longer bake
    assert key(demo, "other code") != base


def test_dataset_density_scale_is_read_and_checked(tmp_path: Path) -> None:
    path = tmp_path / "dataset.json"
    assert density_scale({"smoke": {"present": True}}, path) == 1.0  # datasets made before the axis
    assert density_scale({"smoke": {"density_scale": 0}}, path) == 0.0
    for bad in (-1.0, float("nan"), "2", True):
        with pytest.raises(DatasetError, match=r"dataset.json: field 'smoke.density_scale' must be a finite number"):
            density_scale({"smoke": {"density_scale": bad}}, path)


SCALES = (0.25, 0.5, 0.0)  # thin smoke: the demo's own (k = 1) leaves most smoke pixels opaque


@pytest.fixture(scope="module")
def scaled_demo(tmp_path_factory: pytest.TempPathFactory) -> dict[float, Path]:
    """The demo at 48x36, 3 RGB frames, RGB only, generated at each of SCALES in turn with one bake store."""
    from generator.api import generate

    root = tmp_path_factory.mktemp("density")
    store = root / "bakes"
    out = {}
    for k in SCALES:
        out[k] = generate(PRESET_DIR / "demo.yaml", root / f"k{k:g}", show_progress=False, frames=3,
                          resolution=(48, 36), samples=64, passes="rgb.smoky,rgb.clean,rgb.smoke_alpha",
                          density_scale=k, bake_store=store)
        if k == SCALES[0]:
            cache = sorted(p for p in store.rglob("*") if p.is_file())
            before = {p: (p.stat().st_mtime_ns, p.stat().st_size) for p in cache}
    after = {p: (p.stat().st_mtime_ns, p.stat().st_size) for p in before}
    assert after == before, "the bake store changed: a later density re-simulated"
    return out


def _meta(dataset: Path) -> dict:
    return json.loads((dataset / "dataset.json").read_text())


def _alphas(dataset: Path) -> np.ndarray:
    return np.stack([read_exr_channel(p, "A") for p in sorted((dataset / "rgb" / "smoke_alpha").glob("*.exr"))])


@pytest.mark.blender
def test_one_bake_serves_every_density(scaled_demo: dict[float, Path]) -> None:
    metas = [_meta(scaled_demo[k]) for k in SCALES]
    assert {m["bake"]["sha256"] for m in metas} == {metas[0]["bake"]["sha256"]}
    assert [m["bake"]["reused"] for m in metas] == [False, True, True]
    assert metas[0]["timings_s"]["bake"] > 0
    assert all(m["timings_s"]["bake"] is None for m in metas[1:])  # no bake stage ran
    base = metas[0]["optics"]["coefficients_per_unit_density"]
    for k, meta in zip(SCALES, metas):
        assert meta["smoke"]["density_scale"] == k
        coeffs = meta["optics"]["coefficients_per_unit_density"]
        assert coeffs["absorb_density"] == pytest.approx(k / SCALES[0] * base["absorb_density"])


@pytest.mark.blender
def test_opacity_follows_the_power_law(scaled_demo: dict[float, Path]) -> None:
    """Twice the density: alpha' = 1 - (1 - alpha)^2. Exact per ray; a pixel averages rays whose
    transmittance differs under its 1.5-pixel filter, which makes alpha' a little lower than the
    power of the pixel's mean (Jensen), so the means are compared over every pixel (no selection
    by a noisy alpha) with a tolerance between that and the nearest wrong exponent."""
    thin, double = _alphas(scaled_demo[0.25]), _alphas(scaled_demo[0.5])
    predicted = 1.0 - (1.0 - thin) ** 2
    assert (predicted > 0.05).sum() > 100
    assert double.mean() == pytest.approx(predicted.mean(), rel=0.03)
    for wrong in (1.5, 2.5):  # a wrong exponent is far outside that
        assert abs(double.mean() - (1.0 - (1.0 - thin) ** wrong).mean()) > 0.06 * double.mean()


@pytest.mark.blender
def test_zero_density_is_the_smoke_free_scene(scaled_demo: dict[float, Path]) -> None:
    assert np.all(_alphas(scaled_demo[0.0]) == 0.0)
    # The frames show no smoke, so the dataset says so: a trainer plans no smoke for it.
    assert _meta(scaled_demo[0.0])["smoke"]["present"] is False
    assert _meta(scaled_demo[0.5])["smoke"]["present"] is True

    def psnr(dataset: Path) -> float:
        stems = sorted(p.name for p in (dataset / "rgb" / "clean").glob("*.png"))
        return float(np.mean([psnr_u8(read_png(dataset / "rgb" / "smoky" / s), read_png(dataset / "rgb" / "clean" / s))
                              for s in stems]))

    clear, smoky = psnr(scaled_demo[0.0]), psnr(scaled_demo[0.5])
    # k = 0: the smoky image is the clean one up to render noise; with smoke it is not.
    assert clear > 35.0 and smoky < clear - 5.0, (clear, smoky)
    for stem in sorted(p.name for p in (scaled_demo[0.0] / "rgb" / "clean").glob("*.png")):
        # Same cameras, same clean render, whatever the density.
        assert np.array_equal(read_png(scaled_demo[0.0] / "rgb" / "clean" / stem),
                              read_png(scaled_demo[0.5] / "rgb" / "clean" / stem))
