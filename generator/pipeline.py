"""generate-scene end to end: plan → worker (bake + renders) → post-processing → metadata
→ validation → atomic move into place.

All work happens in a staging folder beside the output (`.NAME.partial`). A rerun of
the same spec and seed resumes there: the bake and every finished image are kept. The
dataset appears at its final path only once complete and valid. With a bake store the bake
lives there instead, under its key (`generator.bakes`), and outlives the dataset, so another
dataset of the same simulation (another density scale, image size or seed) only renders.
"""
from __future__ import annotations

import json
import logging
import os
import platform
import shutil
import time
from importlib import metadata
from pathlib import Path
from typing import Any

from tqdm import tqdm

from generator import postprocess
from generator.dataset_stats import scene_stats
from generator.assets import Manifest, load_manifest
from generator.bakes import bake_folder, bake_in, bake_key, is_baked
from contracts.atomic import write_json
from contracts.source import code_digest
from contracts.dataset_format import (FORMAT, FORMAT_VERSION, PASS_FILES, file_path, has_frame, transforms_name,
                                     validate_dataset)
from generator.errors import GeneratorError
from generator.job import (Plan, effective_denoise, load_scene_meshes, make_job, make_plan, resolve_asset_materials,
                           smoke_coefficients, without_absent_passes)
from generator.optical_depth import Calibration, SmokeCalibrator, dataset_alphas, mean_optical_depth
from generator.optics.sensor import ThermalSensor, ThermalSensorConfig
from generator.rig import FrameSample, Intrinsics
from generator.spec import SceneSpec
from generator.worker_client import run_worker

log = logging.getLogger("generate-scene")
STAGING_MARK = "staging.json"


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist, key in (("smokeseer-synth", "smokeseer_synth"), ("bpy", "bpy"), ("numpy", "numpy"),
                      ("miepython", "miepython"), ("colour-science", "colour_science"), ("OpenEXR", "openexr"),
                      ("trimesh", "trimesh")):
        try:
            out[key] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[key] = "not installed"
    return out


def render_code_digest() -> str:
    """Digest of the code that turns a spec into images: this module's and the Blender worker's
    project imports (docstrings and comments excluded, package data such as presets included)."""
    return code_digest("generator.pipeline", "blender.worker")


def _staging(out: Path, spec: SceneSpec, code: str) -> Path:
    """The staging folder for this spec: reused only when both the spec hash and the render code
    digest match (images from other code are not this code's output), else replaced."""
    work = out.parent / f".{out.name}.partial"
    mark = work / STAGING_MARK
    if work.exists():
        previous = json.loads(mark.read_text()) if mark.exists() else {}
        if previous.get("spec_sha256") != spec.sha256():
            log.info("discarding stale staging folder %s (different spec)", work)
        elif previous.get("code_sha256") != code:
            log.info("discarding stale staging folder %s (different generator code: %s, now %s)", work,
                     str(previous.get("code_sha256", "not recorded"))[:12], code[:12])
        else:
            log.info("resuming from %s", work)
            return work
        shutil.rmtree(work)
    (work / "dataset").mkdir(parents=True)
    write_json(mark, {"spec_sha256": spec.sha256(), "code_sha256": code, "scene": spec.name})
    return work


def sensor_for(spec: SceneSpec) -> ThermalSensor:
    """The thermal camera model; its radiance range spans the scene's temperatures."""
    mats = spec.materials.values()
    t_lo = min([spec.lights.sky_temperature_k] + [m.temperature_k - m.temperature_variation_k / 2 for m in mats])
    t_hi = max([spec.lights.ambient_temperature_k] + [m.temperature_k + m.temperature_variation_k / 2 for m in mats]
               + [s.temperature_k for s in spec.sources if s.kind != "smoke"])
    cam = spec.rig.thermal
    options = {"t_min_k": max(1.0, t_lo - 10.0), "t_max_k": t_hi + 20.0, **cam.sensor}
    try:
        config = ThermalSensorConfig(width=cam.width, height=cam.height, **options)
    except (TypeError, ValueError) as exc:
        raise GeneratorError(f"rig.thermal.sensor: {exc}") from None
    return ThermalSensor(config, seed=spec.seed)


def _transforms(modality: str, k: Intrinsics, fps: float, offset: float, frames: list[FrameSample]) -> dict[str, Any]:
    return {
        "modality": modality, "camera_model": "PINHOLE", "w": k.width, "h": k.height,
        "fl_x": k.fl_x, "fl_y": k.fl_y, "cx": k.cx, "cy": k.cy, "camera_angle_x": k.camera_angle_x,
        "fps": fps, "time_offset_s": offset,
        "frames": [{"index": f.index, "file_stem": f.stem, "timestamp_s": f.timestamp_s, "time": f.time,
                    "sim_frame": f.sim_frame, "split": f.split, "transform_matrix": f.c2w.tolist()}
                   for f in frames],
    }


def _frame_done(out: Path, modality: str, passes: tuple[str, ...], frame: FrameSample) -> bool:
    return all(file_path(out, pf, frame.stem).exists() for p in passes if has_frame(modality, p, frame.split)
               for pf in PASS_FILES[(modality, p)])


def _postprocess(spec: SceneSpec, plan: Plan, work: Path, sensor: ThermalSensor | None, show: bool) -> float:
    out = work / "dataset"
    ctx = postprocess.PostContext(
        raw=work / "raw", out=out, requested=spec.passes, mask_threshold=spec.smoke.mask_threshold,
        sensor=sensor)
    t0 = time.perf_counter()
    for modality, passes in spec.passes.items():
        frames = plan.frames[modality]
        for frame in tqdm(frames, desc=f"post {modality}", unit="frame", disable=not show, leave=False):
            if _frame_done(out, modality, passes, frame):
                continue
            if modality == "rgb":
                postprocess.finish_rgb_frame(ctx, frame.stem, frame.split)
            else:
                postprocess.finish_thermal_frame(ctx, frame.stem, frame.index)
    return time.perf_counter() - t0


def rendered_coefficients(spec: SceneSpec, plan: Plan, calibration: Calibration | None = None) -> dict[str, Any] | None:
    """The smoke coefficients per unit grid density as rendered: the density scale k (times the
    optical-depth calibration's, when there is one) times the spec's (the worker applies the
    product as a weight on every coefficient)."""
    if not spec.has_smoke:
        return None
    coeffs = smoke_coefficients(spec, plan.optics)
    k = spec.smoke.density_scale * (calibration.scale if calibration is not None else 1.0)
    return {**coeffs, **{name: k * coeffs[name] for name in ("scatter_density", "absorb_density", "lwir_absorption")}}


def _metadata(spec: SceneSpec, plan: Plan, sensor: ThermalSensor | None, summary: dict[str, Any],
              timings: dict[str, Any], code: str, bake: dict[str, Any] | None,
              calibration: Calibration | None, achieved: float | None) -> dict[str, Any]:
    optics = plan.optics
    coeffs = rendered_coefficients(spec, plan, calibration)
    meta: dict[str, Any] = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "scene": spec.name, "seed": spec.seed,
        "spec_sha256": spec.sha256(), "code_sha256": code,
        "duration_s": plan.timeline.duration_s, "sim_fps": spec.sim.fps,
        "passes": {m: list(p) for m, p in spec.passes.items()},
        # At k = 0 the bake is there but no frame shows smoke: present is what the frames show.
        "smoke": {"present": spec.has_smoke and spec.smoke.density_scale > 0,
                  "fire": spec.has_fire, "static": spec.sim.static,
                  "mask_threshold": spec.smoke.mask_threshold, "density": spec.smoke.density,
                  "density_scale": spec.smoke.density_scale,
                  "particles": spec.smoke.particles, "sources": len(spec.sources),
                  "grids": summary.get("grids", [])},
        "optics": {**optics.describe(),
                   "ambient_temperature_k": spec.lights.ambient_temperature_k,
                   "sky_temperature_k": spec.lights.sky_temperature_k,
                   "coefficients_per_unit_density": coeffs},
        "bake": bake,
        "render_restarts": summary.get("render_restarts", 0),
        "render": {m: {"samples": cam.samples, "clean_samples": cam.clean_samples,
                       "denoise": effective_denoise(spec, cam), "volume_step_rate": cam.volume_step_rate}
                   for m, cam in (("rgb", spec.rig.rgb), ("thermal", spec.rig.thermal)) if spec.passes.get(m)},
        "stats": {},
        "versions": {**versions(), "blender": summary.get("bpy", "")},
        "timings_s": timings,
    }
    if calibration is not None:  # achieved: measured on the dataset's RGB smoke opacity, as rendered (at k)
        meta["smoke"]["optical_depth"] = {**calibration.describe(), "achieved": achieved}
    if sensor is not None:
        meta["thermal_sensor"] = sensor.describe()
    return meta


def made_from(out: Path, spec: SceneSpec) -> bool:
    """Whether a finished dataset is at `out` and was made from this very spec."""
    meta = out / "dataset.json"
    return meta.is_file() and json.loads(meta.read_text()).get("spec_sha256") == spec.sha256()


def generate(spec: SceneSpec, out: Path, manifest: Manifest | None = None, source: str = "spec",
             threads: int | None = None, force: bool = False, show_progress: bool = True,
             bake_store: Path | None = None) -> Path:
    """Generate the dataset for `spec` at `out`; resumes an interrupted run of the same spec.
    With `bake_store`, the bake is kept there and a finished bake of the same key is reused."""
    out = Path(out).resolve()
    if out.exists() and not force:
        raise GeneratorError(f"{out}: already exists (use --force to replace it)")
    started = time.perf_counter()
    manifest = manifest or load_manifest()
    spec = without_absent_passes(spec)
    spec = resolve_asset_materials(spec, manifest, source)
    plan = make_plan(spec)
    meshes = load_scene_meshes(spec, manifest, source)
    code = render_code_digest()
    work = _staging(out, spec, code)
    threads = threads or max(1, os.cpu_count() or 1)
    job = make_job(spec, plan, manifest, source, work, threads, meshes)
    bake: dict[str, Any] | None = None  # a smoke-free scene, or passes that never show the smoke: no bake
    if spec.has_smoke and not job.sources:
        log.info("no requested pass shows the smoke: the scene renders without its smoke domain, no bake")
    if job.sources:
        key = bake_key(job, code)
        if bake_store is not None:
            job = bake_in(job, bake_folder(Path(bake_store).resolve(), spec.name, key))
        bake = {"sha256": key, "reused": is_baked(job)}
        if bake["reused"]:
            log.info("reusing the finished bake in %s", Path(job.blend_path).parent)
    log.info("scene %s: %d RGB + %d thermal frames, passes %s, sim %d^3 over %d frames",
             spec.name, len(plan.frames["rgb"]), len(plan.frames["thermal"]),
             ",".join(f"{m}.{p}" for m, ps in spec.passes.items() for p in ps), spec.sim.resolution,
             plan.last_frame)
    calibrator = None
    if job.sources and spec.smoke.optical_depth is not None:
        calibrator = SmokeCalibrator(spec.smoke.optical_depth, work, source, show_progress)
    summary = run_worker(job, work, show_progress, calibrator) if job.passes else {"timings": {}, "passes": {}}
    log.info("worker finished in %.1f s", summary.get("wall_s", 0.0))
    sensor = sensor_for(spec) if spec.passes.get("thermal") else None
    post_s = _postprocess(spec, plan, work, sensor, show_progress)
    log.info("post-processing finished in %.1f s", post_s)
    dataset = work / "dataset"
    for modality in spec.passes:
        cam = spec.rig.rgb if modality == "rgb" else spec.rig.thermal
        write_json(dataset / transforms_name(modality),
                    _transforms(modality, plan.intrinsics[modality], cam.fps, cam.time_offset_s,
                                plan.frames[modality]))
    (dataset / "scene.yaml").write_text(spec.to_yaml())
    timings = {"bake": summary["timings"].get("bake"), "build": summary["timings"].get("build"),
               "worker": summary.get("wall_s"), "postprocess": post_s,
               "render": {k: v["seconds_per_frame"] for k, v in summary["passes"].items()},
               "total": time.perf_counter() - started}
    calibration = calibrator.result if calibrator is not None else None
    achieved = None
    if calibration is not None:
        timings["calibration"] = calibrator.seconds
        if "smoke_alpha" in spec.passes.get("rgb", ()):
            achieved = mean_optical_depth(dataset_alphas(dataset))
    meta = _metadata(spec, plan, sensor, summary, timings, code, bake, calibration, achieved)
    meta["stats"] = scene_stats(dataset, meta)
    write_json(dataset / "dataset.json", meta)
    validate_dataset(dataset)
    if out.exists():
        shutil.rmtree(out)
    os.replace(dataset, out)
    shutil.rmtree(work)
    log.info("dataset written to %s in %.1f s", out, time.perf_counter() - started)
    return out
