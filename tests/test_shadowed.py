"""The shadowed ground truth (`rgb.shadowed`): the smoke in the scene for every ray but the camera's.

On a tiny real scene (bpy, Mantaflow, Cycles): a plume over a checkered ground, a low sun, a
camera looking straight down beside the plume, so part of the ground lies in the plume's shadow
and is seen past it. Which pixels the smoke can touch is decided geometrically, from the smoke
domain's box: a camera ray that misses the box meets no smoke, a ground point whose ray to the sun
misses it is lit as without smoke. Render noise is measured on the same pixels, from the clean
pass rendered again at another seed.
"""
from __future__ import annotations

import json
import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import ndimage

from contracts.dataset_format import validate_dataset
from contracts.errors import DatasetError
from contracts.imageio import image01, read_exr_channel, read_png, write_exr
from generator.api import resolve_spec
from generator.assets import load_manifest
from generator.cli import main as cli_main
from generator.errors import GeneratorError
from generator.ground_truth_refresh import (SMOKE_CHECK_RMS, Refresh, opacity_difference, refresh_ground_truth,
                                           refresh_plan, same_cameras)
from generator.job import resolve_asset_materials
from generator.pipeline import generate
from generator.presets import preset_path
from generator.spec import Overrides, parse_passes
from tests.test_smokeseer_data import write_splat_dataset

DOMAIN_CENTER, DOMAIN_SIZE, SIM_RESOLUTION = (0.0, 0.0, 0.9), (1.2, 1.2, 1.8), 16
SUN_ELEVATION_DEG = 30.0  # azimuth 0: the sun lies towards +x, the plume's shadow falls towards -x


def _spec_file(root: Path) -> Path:
    """The demo preset cut down: its ground alone, a dense plume, the sun low in +x, and a camera
    6 m up looking down at the ground left of the plume; 64 samples for every pass, no denoiser,
    so the smoky and the shadowed frames differ by nothing but what the smoke does."""
    spec = yaml.safe_load(preset_path("demo").read_text())
    spec.update(name="shadow_test", frames=2, test_every=2)
    spec["objects"] = [o for o in spec["objects"] if o["name"] == "ground"]
    spec["materials"] = {"concrete": spec["materials"]["concrete"]}
    spec["sim"].update(center=list(DOMAIN_CENTER), size=list(DOMAIN_SIZE), resolution=SIM_RESOLUTION, warmup_s=2.0)
    spec["sources"] = [{"type": "smoke", "position": [0.0, 0.0, 0.2], "radius": 0.25, "rate": 1.0,
                        "temperature_k": 330.0}]
    spec["smoke"].update(density=1.0, extinction_per_m=24.0)
    spec["lights"].update(sun_elevation_deg=SUN_ELEVATION_DEG, sun_azimuth_deg=0.0, sun_strength=4.0)
    spec["rig"]["trajectory"] = {"kind": "flyover", "start": [-1.2, -0.3, 6.0], "end": [-1.2, 0.3, 6.0],
                                 "look_from": [-1.2, 0.0, 0.0], "look_to": [-1.2, 0.0, 0.0]}
    spec["rig"]["rgb"] = {"width": 48, "height": 36, "fov_deg": 55.0, "fps": 12.0, "samples": 64,
                          "clean_samples": 64, "denoise": "none"}
    spec["passes"] = ["rgb"]
    path = root / "shadow_test.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.fixture(scope="module")
def shadow_scene(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The scene with every RGB pass, and its clean pass alone at another seed (no bake)."""
    root = tmp_path_factory.mktemp("shadow")
    path = _spec_file(root)
    spec, source = resolve_spec(path)
    other_seed, _ = resolve_spec(path, Overrides(seed=1, passes="rgb.clean"))
    return (generate(spec, root / "full", source=source, show_progress=False),
            generate(other_seed, root / "seed1", source=source, show_progress=False))


def _box_hit(origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Whether each ray meets the smoke domain's box, grown by one voxel (slab test)."""
    voxel = max(DOMAIN_SIZE) / SIM_RESOLUTION
    lo = np.asarray(DOMAIN_CENTER) - np.asarray(DOMAIN_SIZE) / 2 - voxel
    hi = np.asarray(DOMAIN_CENTER) + np.asarray(DOMAIN_SIZE) / 2 + voxel
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origin) / direction, (hi - origin) / direction
    near, far = np.nanmax(np.minimum(t1, t2), axis=-1), np.nanmin(np.maximum(t1, t2), axis=-1)
    return far >= np.maximum(near, 0.0)


def _regions(dataset: Path, frame: dict, transforms: dict) -> tuple[np.ndarray, np.ndarray]:
    """Ground pixels whose camera ray misses the smoke, and of those, the ones whose sun ray does
    too; both kept 2 pixels from the pixels that may see it (Cycles' pixel filter is 1.5 wide)."""
    h, w, c2w = transforms["h"], transforms["w"], np.asarray(frame["transform_matrix"])
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = np.stack([(u - transforms["cx"]) / transforms["fl_x"], -(v - transforms["cy"]) / transforms["fl_y"],
                     -np.ones_like(u)], axis=-1)
    depth = read_exr_channel(dataset / "rgb" / "depth" / f"{frame['file_stem']}.exr", "Z")
    directions = rays @ c2w[:3, :3].T
    camera_free = ~ndimage.binary_dilation(_box_hit(np.broadcast_to(c2w[:3, 3], directions.shape), directions),
                                           iterations=2) & (depth > 0)
    ground = (rays * depth[..., None]) @ c2w[:3, :3].T + c2w[:3, 3]
    elevation = math.radians(SUN_ELEVATION_DEG)
    to_sun = np.broadcast_to([math.cos(elevation), 0.0, math.sin(elevation)], ground.shape)
    light_free = ~ndimage.binary_dilation(_box_hit(ground, to_sun), iterations=2)
    return camera_free, camera_free & light_free


@pytest.mark.blender
def test_shadowed_is_smoky_off_the_smoke_and_clean_off_its_shadow(shadow_scene: tuple[Path, Path]) -> None:
    """The pass is rendered for the test view alone (frame 1 of 2). Measured (48x36, 64 samples,
    both frames, when every frame had the pass): an independent render differs by 0.0075-0.0077 RMS
    per channel (two seeds of the clean pass). Where no smoke lies on the camera ray, shadowed
    differs from smoky by 0.0011 RMS (same seed: the same paths, up to the camera ray's volume
    sampling); where it lies on neither that ray nor the ray to the sun, from clean by 0.0034 RMS
    and a mean of -0.0010 (a quarter of an 8-bit level: the plume hides a little sky and ground
    bounce); where the sun's ray crosses the smoke domain it is 0.05 darker (the shadow), and
    where the smoke is in view it is 0.12 from smoky. Tolerance: render noise, the RMS difference
    of two independent renders, for both equalities, and one 8-bit level for the mean."""
    full, seed1 = shadow_scene
    transforms = json.loads((full / "transforms_rgb.json").read_text())
    tests = [f for f in transforms["frames"] if f["split"] == "test"]
    assert sorted(p.stem for p in (full / "rgb" / "shadowed").iterdir()) == [f["file_stem"] for f in tests] == ["0001"]
    for frame in tests:
        stem = frame["file_stem"]
        smoky, clean, shadowed = (image01(read_png(full / "rgb" / name / f"{stem}.png"))
                                  for name in ("smoky", "clean", "shadowed"))
        alpha = read_exr_channel(full / "rgb" / "smoke_alpha" / f"{stem}.exr", "A")
        camera_free, unlit_free = _regions(full, frame, transforms)
        lit_through = camera_free & ~unlit_free
        assert camera_free.sum() > 500 and unlit_free.sum() > 300 and lit_through.sum() > 100
        assert alpha[camera_free].max() == 0.0  # the geometry agrees with the smoke-opacity pass
        noise = float(np.sqrt(np.mean((clean - image01(read_png(seed1 / "rgb" / "clean" / f"{stem}.png"))) ** 2)))

        def rms(a: np.ndarray, b: np.ndarray, where: np.ndarray) -> float:
            return float(np.sqrt(np.mean((a[where] - b[where]) ** 2)))

        assert 0.002 < noise < 0.02, noise
        assert rms(shadowed, smoky, camera_free) < noise
        assert rms(shadowed, clean, unlit_free) < noise
        assert abs(float((shadowed - clean)[unlit_free].mean())) < 1 / 255
        assert float((clean - shadowed)[lit_through].mean()) > 5 / 255  # the shadow is there
        in_view = alpha > 0.3
        assert in_view.sum() > 20 and float(np.abs(shadowed - smoky)[in_view].mean()) > 10 * noise


@pytest.mark.blender
def test_shadowed_is_added_to_a_finished_dataset_alone(shadow_scene: tuple[Path, Path], tmp_path: Path) -> None:
    """A dataset made without the pass gets it rendered alone, the simulation baked again and
    checked against the dataset's smoke opacity: the same frames as generating it with the pass,
    and no other file but dataset.json and scene.yaml changes. Smoke that is not the dataset's is
    refused before anything is swapped in, and the render is kept for the next attempt."""
    full, _ = shadow_scene
    spec, source = resolve_spec(_spec_file(tmp_path))
    spec = resolve_asset_materials(spec, load_manifest(), source)
    lacking = generate(replace(spec, passes=parse_passes("rgb.smoky,rgb.clean,rgb.depth,rgb.smoke_alpha", "t")),
                       tmp_path / "lacking", show_progress=False)
    assert refresh_plan(lacking, spec) == Refresh(resampled={}, added={"rgb": ("shadowed",)})
    before = {p.relative_to(lacking): p.read_bytes() for p in lacking.rglob("*") if p.is_file()}

    alpha_file = lacking / "rgb" / "smoke_alpha" / "0000.exr"
    alpha = read_exr_channel(alpha_file, "A")
    write_exr(alpha_file, {"A": np.clip(alpha * 0.5, 0, 1)})  # another simulation's smoke
    with pytest.raises(GeneratorError, match=r"dataset.json: the simulation baked again is not the dataset's smoke"):
        refresh_ground_truth(lacking, spec, show_progress=False)
    assert not (lacking / "rgb" / "shadowed").exists()
    alpha_file.write_bytes(before[Path("rgb/smoke_alpha/0000.exr")])

    refresh_ground_truth(lacking, spec, show_progress=False)  # resumes from the kept render
    after = {p.relative_to(lacking): p.read_bytes() for p in lacking.rglob("*") if p.is_file()}
    added = {k for k in after if k.parts[:2] == ("rgb", "shadowed")}
    assert added == {Path("rgb/shadowed/0001.png")} and set(after) - set(before) == added  # the test view
    assert {k for k in before if before[k] != after[k]} == {Path("dataset.json"), Path("scene.yaml")}
    for k in added:
        assert after[k] == (full / k).read_bytes(), k
    meta = validate_dataset(lacking)
    assert meta["passes"]["rgb"] == ["smoky", "clean", "shadowed", "depth", "smoke_alpha"]
    assert meta["spec_sha256"] == spec.sha256() and refresh_plan(lacking, spec) is None
    check = meta["passes_added"]["smoke_check"]
    assert check["frames"] == 2 and check["max_frame_rms"] <= SMOKE_CHECK_RMS
    assert meta["stats"]["test_views"]["psnr_shadowed_vs_clean"] is not None
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir()), "staging folder left behind"

    # The statistics of a finished dataset are computed again from its files alone.
    stats = meta.pop("stats")
    (lacking / "dataset.json").write_text(json.dumps(meta))
    assert cli_main(["--update-stats", str(lacking)]) == 0
    assert json.loads((lacking / "dataset.json").read_text())["stats"] == stats


def test_the_smoke_check_passes_estimator_noise_and_refuses_other_smoke() -> None:
    """A plume rendered by the older all-or-nothing opacity estimator (each pixel a binomial share
    of its samples) passes the check against its exact opacity, thin (256 samples: 0.013 RMS per
    pixel, as on house) or dense (32 samples: 0.046, past rover's 0.035), though per pixel, or over
    blocks against the fixed tolerance alone, the dense one would fail. The same plume three pixels
    further on, or at 0.8 of its density, fails under either noise."""
    y, x = np.mgrid[0:150, 0:200].astype(np.float64)

    def plume(dx: float = 0.0, scale: float = 1.0, peak: float = 0.4) -> np.ndarray:
        return scale * peak * np.exp(-((x - 100 - dx) ** 2 + (y - 60) ** 2) / (2 * 25.0 ** 2))

    def passes(a: np.ndarray, b: np.ndarray) -> bool:  # the refresh refuses a share over 1
        return opacity_difference(a, b).share_of_allowed <= 1.0

    rng = np.random.default_rng(0)
    thin = rng.binomial(256, plume()) / 256
    dense = rng.binomial(32, plume(peak=0.9)) / 32
    assert opacity_difference(thin, plume()).pixel_rms > 0.01
    assert opacity_difference(dense, plume(peak=0.9)).pixel_rms > 0.04
    assert opacity_difference(dense, plume(peak=0.9)).block_rms > SMOKE_CHECK_RMS  # a fixed tolerance would refuse
    assert passes(thin, plume()) and passes(dense, plume(peak=0.9))
    assert not passes(thin, plume(dx=3.0)) and not passes(thin, plume(scale=0.8))
    assert not passes(dense, plume(dx=3.0, peak=0.9)) and not passes(dense, plume(scale=0.8, peak=0.9))
    ragged = opacity_difference(plume()[:39, :50] + 1, plume()[:39, :50])  # whole blocks only
    assert ragged.block_rms == ragged.pixel_rms == 1.0 and ragged.noise_block_rms < 1e-12


def test_cameras_computed_again_agree_to_rounding_only() -> None:
    """Poses computed again on another CPU may differ in the last bit (house: 2.2e-16), and pass;
    a pose moved by a micrometre, another timestamp or a missing frame does not."""
    pose = [[0.8825187214943059, 0.15642575271446102, -0.4434993687704301, -12.59322033898305], [0, 0, 0, 1.0]]
    cams = {"camera_angle_x": 0.96, "frames": [{"file_stem": "0000", "time": 0.5, "transform_matrix": pose}]}
    again = json.loads(json.dumps(cams))
    again["frames"][0]["transform_matrix"][0][0] = 0.882518721494306
    assert same_cameras(cams, again)
    moved = json.loads(json.dumps(cams))
    moved["frames"][0]["transform_matrix"][0][3] += 1e-6
    later = json.loads(json.dumps(cams))
    later["frames"][0]["time"] = 0.5 + 1e-6
    assert not same_cameras(cams, moved) and not same_cameras(cams, later)
    assert not same_cameras(cams, {**cams, "frames": []}) and not same_cameras(cams, {"frames": cams["frames"]})


def test_refresh_of_no_dataset_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert cli_main(["--preset", "demo", "--out", str(tmp_path / "none"), "--refresh", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"generate-scene: error: {tmp_path / 'none'}: no finished dataset to render ground truth into"]
    assert list(tmp_path.iterdir()) == []


def test_the_validator_takes_a_dataset_with_and_without_shadowed(tmp_path: Path) -> None:
    with_pass = write_splat_dataset(tmp_path / "with", n_rgb=4, n_thermal=3)
    without = write_splat_dataset(tmp_path / "without", n_rgb=4, n_thermal=3, shadowed=False)
    assert "shadowed" in validate_dataset(with_pass)["passes"]["rgb"]
    assert "shadowed" not in validate_dataset(without)["passes"]["rgb"]
    # A test-view pass: frame 2 is the test view, so only its file is there and needed; a dataset
    # made before the rule, with the pass on every frame, stays valid.
    assert sorted(p.name for p in (with_pass / "rgb" / "shadowed").iterdir()) == ["0002.png"]
    shutil.copyfile(with_pass / "rgb" / "clean" / "0000.png", with_pass / "rgb" / "shadowed" / "0000.png")
    validate_dataset(with_pass)
    (with_pass / "rgb" / "shadowed" / "0002.png").unlink()
    with pytest.raises(DatasetError, match=r"rgb/shadowed/0002\.png: missing file"):
        validate_dataset(with_pass, check_images=False)
    meta = json.loads((without / "dataset.json").read_text())
    meta["passes"]["thermal"].append("shadowed")
    (without / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match="unknown pass thermal.shadowed"):
        validate_dataset(without)
    shutil.rmtree(with_pass)


def test_runs_are_scored_against_shadowed_when_the_dataset_has_it(tmp_path: Path) -> None:
    """metrics.json's *_shadowed scores: a render equal to the shadowed frames scores the cap
    against them and the clean-vs-shadowed PSNR against clean; the smoky input is scored against
    both. Without the pass they are null, and a run written before they existed still reads."""
    from contracts.metrics import PSNR_CAP_DB
    from contracts.results_format import SHADOWED_METRIC_KEYS, ResultsFormatError, read_metrics
    from scenes.load import load_scene
    from smokeseer.evaluation.scoring import TestRenders, score

    def db(a: np.ndarray, b: np.ndarray) -> float:  # PSNR written out here, not taken from contracts.metrics
        return 10 * math.log10(1 / max(float(np.mean((a.astype(np.float64) - b) ** 2)), 1e-10))

    for shadowed in (True, False):
        scene = load_scene(write_splat_dataset(tmp_path / str(shadowed), n_rgb=8, n_thermal=3, shadowed=shadowed))
        idx = scene.rgb.indices("test")
        truth = scene.rgb.shadowed if shadowed else scene.rgb.clean
        assert truth is not None and len(idx) == 2
        renders = TestRenders([scene.rgb.frames[i].file_stem for i in idx], [truth[i] for i in idx],
                              [np.ones(truth[i].shape[:2]) for i in idx], [None for _ in idx],
                              [np.ones(truth[i].shape[:2]) for i in idx], [truth[i] for i in idx])
        metrics = score(renders, scene)["metrics"]
        if not shadowed:
            assert scene.rgb.shadowed is None and all(metrics[k] is None for k in SHADOWED_METRIC_KEYS)
            continue
        clean, smoky = scene.rgb.clean, scene.rgb.images
        assert metrics["psnr_shadowed"] == pytest.approx(PSNR_CAP_DB) and metrics["ssim_shadowed"] == pytest.approx(1.0)
        assert metrics["psnr"] == pytest.approx(np.mean([db(truth[i], clean[i]) for i in idx]), rel=1e-6)
        assert metrics["psnr_input_shadowed"] == pytest.approx(np.mean([db(smoky[i], truth[i]) for i in idx]), rel=1e-6)
        assert metrics["psnr_input_shadowed"] != pytest.approx(metrics["psnr_input"])
    run = tmp_path / "run"
    run.mkdir()
    doc = {"format": "smokeseer-synth-results", "format_version": 1, "scene": "s", "dataset": "d", "method": "full",
           "profile": "quick", "seed": 0, "status": "ok", "wall_time_s": {}, "versions": {}, "config_sha256": "x",
           "provenance": {"commit": None, "version": "0", "source_digest": "x", "threads": 1, "machine": {}},
           "metrics": {"psnr": 20.0, "ssim": 0.5, "lpips": None, "lpips_status": "", "psnr_input": 18.0,
                       "depth_absrel": None, "depth_rmse": None, "mask_iou": None}}
    (run / "metrics.json").write_text(json.dumps(doc))
    assert read_metrics(run)["metrics"]["psnr"] == 20.0  # written before the shadowed scores existed
    doc["metrics"]["psnr_input_shadowed"] = float("nan")
    (run / "metrics.json").write_text(json.dumps(doc))
    with pytest.raises(ResultsFormatError, match="field 'metrics.psnr_input_shadowed' must be a finite number"):
        read_metrics(run)
