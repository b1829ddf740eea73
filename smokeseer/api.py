"""``train_and_evaluate``: load → Stage 1 → Stage 2 → Stage 3 → evaluate → outputs.

The metrics harness calls this function; the CLI is a thin wrapper. Every run leaves a
metrics.json, with ``status: "failed"`` and the error when something went wrong.
"""
from __future__ import annotations

import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

import smokeseer
from smokeseer.cameras import sample_in_view
from smokeseer.config import TrainConfig, make_config
from smokeseer.data import ModalityData, SceneData, load_scene
from smokeseer.depth_prior import DepthPriorMaps, monocular_depth_prior, rendered_depth_prior
from smokeseer.evaluate import lpips_weights_from_env, quick_test_psnr, score, write_plys, write_renders
from smokeseer.model import SceneModel
from smokeseer.stage1 import run_stage1
from smokeseer.stage2 import train_stage2, views_of
from smokeseer.stage3 import Stage3Switches, build_scene_model, train_stage3
from smokeseer.trainutil import RunContext, RunLog

RESULTS_FORMAT = "smokeseer-synth-results"
RESULTS_FORMAT_VERSION = 1


def _versions() -> dict[str, str]:
    return {"smokeseer_synth": getattr(smokeseer, "__version__", "0.1.0"), "torch": torch.__version__,
            "numpy": np.__version__, "python": platform.python_version()}


def _sample(mod: ModalityData, n: int, bounds: Any, rng: np.random.Generator) -> np.ndarray:
    idx = mod.indices("train")
    f = [mod.frames[i] for i in idx]
    return sample_in_view(bounds, n, np.stack([x.viewmat for x in f]), np.stack([x.K for x in f]),
                          np.array([x.width for x in f]), np.array([x.height for x in f]), rng)


def switches_for(cfg: TrainConfig, scene: SceneData) -> Stage3Switches:
    """Leave out what the data does not need: no smoke in the masks → no smoke Gaussians;
    static smoke → no deformation network; no thermal → rgb-only."""
    masks = scene.rgb.masks
    smoke_seen = scene.smoke_present and (masks is None or bool((masks[scene.rgb.indices("train")] > 0).any()))
    return Stage3Switches(
        use_thermal=scene.thermal is not None and cfg.mode not in ("rgb-only", "deformable-3dgs"),
        use_smoke=smoke_seen and cfg.mode != "deformable-3dgs",
        use_deform=not scene.smoke_static,
        use_masks=masks is not None,
    )


def _metrics_doc(cfg: TrainConfig, scene_name: str, dataset: Path, status: str) -> dict[str, Any]:
    return {"format": RESULTS_FORMAT, "format_version": RESULTS_FORMAT_VERSION, "scene": scene_name,
            "dataset": str(Path(dataset).resolve()), "method": cfg.mode, "profile": cfg.profile,
            "seed": cfg.seed, "status": status}


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=2, allow_nan=False))
    tmp.replace(path)


def train_and_evaluate(dataset: Path, out: Path, mode: str = "full", profile: str = "quick", seed: int = 0,
                       overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train ``mode`` on ``dataset``, evaluate the held-out views, write RUN_DIR ``out``;
    returns the metrics.json content. Raises DatasetError/ValueError for bad input and
    NaNDetected for a diverged run (after writing a failed metrics.json)."""
    cfg = make_config(mode, profile, seed, overrides)
    dataset, out = Path(dataset), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "checkpoints").mkdir(exist_ok=True)
    (out / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2))
    scene_name = dataset.name
    try:
        return _run(cfg, dataset, out)
    except Exception as exc:
        doc = _metrics_doc(cfg, scene_name, dataset, "failed")
        doc["error"] = f"{type(exc).__name__}: {exc}"
        doc["versions"] = _versions()
        doc["config_sha256"] = cfg.sha256()
        _write_json(out / "metrics.json", doc)
        raise


def _run(cfg: TrainConfig, dataset: Path, out: Path) -> dict[str, Any]:
    if cfg.depth_prior == "mono" and not Path(cfg.mono_weights).is_file():
        raise ValueError(f"mono_weights: no TorchScript file at {cfg.mono_weights!r} (depth_prior=mono "
                         "uses weights on local disk only)")
    torch.manual_seed(cfg.seed)
    wall: dict[str, float] = {}
    t_start = time.perf_counter()
    scene = load_scene(dataset, cfg.max_width)
    log_path = out / "train_log.csv"
    prior_wall = RunLog(log_path).last_wall() if log_path.exists() else 0.0
    t = time.perf_counter()
    report = run_stage1(cfg, scene)
    switches = switches_for(cfg, scene)
    wall["stage1"] = time.perf_counter() - t
    b = report.bounds
    ctx = RunContext(cfg, out, RunLog(log_path, wall_offset=prior_wall),
                     torch.as_tensor(b.center, dtype=torch.float32), b.extent)
    geo = scene.thermal if switches.use_thermal else scene.rgb
    ctx.log_line(f"stage 1: {scene.name}: {len(scene.rgb.frames)} RGB frames "
                 f"({len(scene.rgb.indices('test'))} test), "
                 f"{len(scene.thermal.frames) if scene.thermal else 0} thermal; geometry from {geo.name}; "
                 f"smoke={'on' if switches.use_smoke else 'off'} deform={'on' if switches.use_deform else 'off'} "
                 f"registered={report.registered} extent={b.extent:.3g}")
    rng = np.random.default_rng(cfg.seed)
    init = scene.init_points if scene.init_points is not None and len(scene.init_points) >= 4 else \
        _sample(geo, cfg.stage2.init_points, b, rng)
    dev = ctx.device
    deformable = cfg.mode == "deformable-3dgs"

    def s2_psnr(g: Any, deform: Any, background: Any, it: int) -> float | None:
        if not deformable:
            return None
        m = SceneModel(g, None, None, True, ctx.center, cfg.sh_degree, surface_deform=deform,
                       background_rgb=background)
        return quick_test_psnr(m, scene, dev)

    t = time.perf_counter()
    s2 = train_stage2(ctx, geo, init, deformable=deformable, test_psnr=s2_psnr)
    wall["stage2"] = time.perf_counter() - t
    ctx.log_line(f"stage 2: {s2.gaussians.n} Gaussians from {geo.name} in {wall['stage2']:.1f} s")
    t = time.perf_counter()
    if deformable:
        model = SceneModel(s2.gaussians, None, None, True, ctx.center, cfg.sh_degree, surface_deform=s2.deform,
                           background_rgb=s2.background)
        wall["stage3"] = 0.0
        ctx.log_line("stage 3: skipped (deformable-3dgs baseline has one deformable set)")
    else:
        smoke_pts = _sample(scene.rgb, cfg.stage3.smoke_points, b, rng) if switches.use_smoke else None
        model = build_scene_model(ctx, s2, switches, smoke_pts, scene.smoke_static)
        prior = _depth_prior(cfg, s2.gaussians, scene, dev)
        model = train_stage3(ctx, model, scene.rgb, scene.thermal, switches, prior,
                             test_psnr=lambda m, it: quick_test_psnr(m, scene, dev))
        wall["stage3"] = time.perf_counter() - t
        ctx.log_line(f"stage 3: {model.surface.n} surface + {model.smoke.n if model.smoke else 0} smoke "
                     f"Gaussians in {wall['stage3']:.1f} s")
    t = time.perf_counter()
    renders = write_renders(model, scene, out, dev)
    scores = score(renders, scene, lpips_weights_from_env())
    write_plys(model, out, cfg.smoke_ply_times)
    wall["eval"] = time.perf_counter() - t
    wall["total"] = time.perf_counter() - t_start
    m = scores["metrics"]
    ctx.log_line(f"eval: PSNR surface vs clean {m['psnr']}, smoky input vs clean {m['psnr_input']} "
                 f"in {wall['eval']:.1f} s")
    doc = _metrics_doc(cfg, scene.name, dataset, "ok")
    doc.update(scores)
    doc["wall_time_s"] = {k: round(v, 3) for k, v in wall.items()}
    doc["stages"] = {"registered": report.registered, "registration_rmse": report.registration_rmse,
                     "pose_noise": report.pose_noise, "geometry_modality": geo.name,
                     "smoke_gaussians": model.smoke.n if model.smoke is not None else 0,
                     "surface_gaussians": model.surface.n, "deformation": switches.use_deform}
    doc["versions"] = _versions()
    doc["config_sha256"] = cfg.sha256()
    _write_json(out / "metrics.json", doc)
    return doc


def _depth_prior(cfg: TrainConfig, geometry: Any, scene: SceneData, dev: torch.device) -> DepthPriorMaps | None:
    if cfg.depth_prior == "none" or cfg.mode == "no-depth":
        return None
    idx = scene.rgb.indices("train")
    if cfg.depth_prior == "mono":
        return monocular_depth_prior(Path(cfg.mono_weights), torch.as_tensor(scene.rgb.images[idx], device=dev))
    return rendered_depth_prior(geometry, views_of(scene.rgb, idx, dev))
