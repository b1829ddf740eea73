"""``train_and_evaluate``: load (validating) → Stage 1 → Stage 2 → Stage 3 → evaluate → outputs.

The metrics harness calls this function; the CLI is a thin wrapper. Bad input (config, dataset,
Stage 1) is refused before anything is written to ``out``; once training starts, every run
leaves a metrics.json, with ``status: "failed"`` and the error when something went wrong.
"""
from __future__ import annotations

import platform
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from contracts.atomic import write_json
from contracts.folder_lock import folder_lock, refuse_if_busy
from contracts.provenance import provenance
from contracts.recorded_paths import recorded_path
from contracts.results_format import RESULTS_FORMAT, RESULTS_FORMAT_VERSION, RunWarning
from scenes.cameras import IN_VIEW_FRACTION, sample_in_view
from scenes.load import load_scene
from scenes.scene import ModalityData, SceneData
from scenes.thermal_scale import ThermalScaleSpec
from smokeseer.config import TrainConfig, make_config
from smokeseer.config.streams import numpy_stream, stream_seed
from smokeseer.evaluation.figures import write_test_figures
from smokeseer.evaluation.scoring import (heldout_psnr, score, score_validation, surface_diagnostics, write_plys,
                                           write_renders)
from smokeseer.model.scene import Placed, SceneModel, init_gaussians, render
from smokeseer.stage1.haze_lines import HazeLineSettings, SmokeColourEstimate, estimate_smoke_colour
from smokeseer.stage1.input_checks import input_warnings
from smokeseer.stage1.pipeline import Stage1Report, run_stage1
from smokeseer.train.depth_prior import DepthPriorMaps, file_depth_prior, monocular_depth_prior, rendered_depth_prior
from smokeseer.train.divergence import StageDiverged
from smokeseer.train.mask_floor import estimated_alpha_bound, estimated_dense, never_seen_clear
from smokeseer.train.plan import Stage3Plan, plan_stage3
from smokeseer.train.stage2 import train_stage2, views_of
from smokeseer.train.stage3 import build_scene_model, train_stage3
from smokeseer.train.surface_union import TwoSurfaces, join_surfaces, surface_start
from smokeseer.train.util import RunContext, RunLog


def _versions() -> dict[str, str]:
    return {"torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version()}


def _sample(mod: ModalityData, n: int, bounds: Any, rng: np.random.Generator, note: Callable[[str], None],
            what: str) -> np.ndarray:
    """``n`` random points in ``bounds`` that ``mod``'s training cameras see; those that had to be
    drawn without that check get a ``note`` naming ``what`` they are for."""
    f = [mod.frames[i] for i in mod.indices("train")]
    drawn = sample_in_view(bounds, n, *mod.cameras("train"), np.array([x.width for x in f]),
                           np.array([x.height for x in f]), rng)
    if drawn.unseen:
        note(f"{what} ({mod.name}): {drawn.unseen} of {n} random points lie where fewer than "
             f"{100 * IN_VIEW_FRACTION:.0f} % of the training cameras look (the box barely overlaps their views)")
    return drawn.points


def _init_points(scene: SceneData, report: Stage1Report, mod: ModalityData, n: int, bounds: Any,
                 rng: np.random.Generator, note: Callable[[str], None]) -> np.ndarray:
    """Stage 2's starting points: the capture's SfM points when it has some; else Stage 1's from
    the training frames (``stage2.init_from=images``) filled up to ``n`` with random ones in their
    box; else ``n`` random ones (``_sample``)."""
    if scene.init_points is not None and len(scene.init_points) >= 4:
        return scene.init_points
    given = report.start_points.points if report.start_points is not None else None
    fill = n if given is None else n - len(given)
    if fill <= 0:
        return given
    drawn = _sample(mod, fill, bounds, rng, note, "stage 2 start")
    return drawn if given is None else np.concatenate([given, drawn])


def _metrics_doc(prep: PreparedRun, status: str) -> dict[str, Any]:
    cfg = prep.cfg
    return {"format": RESULTS_FORMAT, "format_version": RESULTS_FORMAT_VERSION, "scene": prep.scene.name,
            "dataset": recorded_path(prep.dataset), "method": cfg.mode, "profile": cfg.profile,
            "seed": cfg.seed, "status": status, "warnings": [w.record() for w in prep.warnings],
            "versions": _versions(), "config_sha256": cfg.sha256(), "provenance": prep.provenance}


@dataclass
class PreparedRun:
    """Everything checked and loaded before the run folder is touched."""

    cfg: TrainConfig
    dataset: Path
    scene: SceneData
    report: Stage1Report
    plan: Stage3Plan
    load_s: float
    provenance: dict[str, Any]
    """Taken before training: a commit made or a file edited during a long run must not be
    credited with its result."""
    warnings: list[RunWarning]
    """What the input checks found (``smokeseer.stage1.input_checks``), thermal-flat included."""


def prepare(dataset: Path, mode: str = "full", profile: str = "quick", seed: int = 0,
            overrides: dict[str, Any] | None = None) -> PreparedRun:
    """Config, loading (a dataset in our format is validated as it is read: its structure and
    every file present, each image checked as it is decoded, once) and Stage 1; raises
    DatasetError/ValueError naming the bad input."""
    t = time.perf_counter()
    code = provenance("smokeseer.api", torch.get_num_threads())
    cfg = make_config(mode, profile, seed, overrides)
    check_device(cfg.device)
    dataset = Path(dataset)
    if cfg.depth_prior == "mono" and not Path(cfg.mono_weights).is_file():
        raise ValueError(f"mono_weights: no TorchScript file at {cfg.mono_weights!r} (depth_prior=mono "
                         "uses weights on local disk only)")
    scene = load_scene(dataset, cfg.max_width, ThermalScaleSpec(cfg.thermal_scale, cfg.thermal_equalised_share),
                       cfg.validation_every)
    report = run_stage1(cfg, scene)
    plan = plan_stage3(cfg, scene)
    warnings = input_warnings(scene, report.bounds) + ([plan.thermal_warning] if plan.thermal_warning else [])
    return PreparedRun(cfg, dataset, scene, report, plan, time.perf_counter() - t, code, warnings)


def train_and_evaluate(dataset: Path, out: Path, mode: str = "full", profile: str = "quick", seed: int = 0,
                       overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train ``mode`` on ``dataset``, evaluate the held-out views, write RUN_DIR ``out``;
    returns the metrics.json content. Raises DatasetError/ValueError for bad input and FolderBusy
    for a run folder another process is training in (nothing is written then), NaNDetected for a
    non-finite run (after writing a failed metrics.json) and StageDiverged for a loss that ran
    away (after writing a diverged one, with no scores). The run folder is locked while it trains
    (``contracts.folder_lock``, the harness's lock: a harness that holds it may call this)."""
    out = Path(out)
    check_run_dir(out)
    refuse_if_busy(out)
    prep = prepare(dataset, mode, profile, seed, overrides)
    with folder_lock(out, wait=False):
        (out / "checkpoints").mkdir(parents=True, exist_ok=True)
        write_json(out / "config.json", prep.cfg.to_dict())
        try:
            return _run(prep, out)
        except StageDiverged as exc:
            doc = _metrics_doc(prep, "diverged")
            doc["error"] = f"{type(exc).__name__}: {exc}"
            doc["diverged"] = exc.record()
            doc["warnings"].append(exc.warning().record())
            write_json(out / "metrics.json", doc)
            raise
        except Exception as exc:
            doc = _metrics_doc(prep, "failed")
            doc["error"] = f"{type(exc).__name__}: {exc}"
            write_json(out / "metrics.json", doc)
            raise


def check_device(device: str) -> None:
    """Refuse, before any work, a device this torch cannot use (one line, not a CUDA traceback)."""
    try:
        dev = torch.device(device)
    except RuntimeError as exc:
        raise ValueError(f"device: {device!r} is not a torch device ({exc})") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device: {device!r} asked for, but this torch {torch.__version__} sees no CUDA GPU "
                         f"(built with CUDA {torch.version.cuda or 'no'}); use --device cpu")


def check_run_dir(out: Path) -> None:
    """Refuse, before any work, a run folder that cannot be made: ``out`` or the nearest of its
    parents that exists must be a directory."""
    existing = next((p for p in (out, *out.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        what = "the run folder" if existing == out else f"a parent of the run folder {out}"
        raise ValueError(f"{existing}: is a file, not a directory ({what})")


def estimate_cpu_seconds(ctx: RunContext, geo: ModalityData, init: np.ndarray) -> float:
    """A lower bound on the training time: one measured forward + backward of the initial
    Gaussians at the training resolution, times the iterations (Stage 3 renders two images per
    iteration, and densification only adds Gaussians)."""
    cfg = ctx.cfg
    t = init_gaussians(init, cfg.stage2.init_opacity, cfg.stage2.init_scale_max * ctx.extent, ctx.device)
    means = t["means"].requires_grad_(True)
    view = views_of(geo, geo.indices("train")[:1], ctx.device)[0]
    placed = Placed(means, t["quats"], t["log_scales"])
    start = time.perf_counter()
    out = render(view, [(placed, torch.sigmoid(t["opacity"]), means.new_full((len(init), geo.channels), 0.5))],
                 None, None)
    out.colors.sum().backward()
    per_iteration = time.perf_counter() - start
    return per_iteration * (cfg.stage2.iterations + 2 * cfg.stage3.iterations)


def _run(prep: PreparedRun, out: Path) -> dict[str, Any]:
    cfg, scene, report, plan = prep.cfg, prep.scene, prep.report, prep.plan
    torch.manual_seed(stream_seed(cfg.seed, "torch.global"))
    wall: dict[str, float] = {"stage1": prep.load_s}
    t_start = time.perf_counter() - prep.load_s
    log_path = out / "train_log.csv"
    prior_wall = RunLog(log_path).last_wall() if log_path.exists() else 0.0
    b = report.bounds
    dev = torch.device(cfg.device)
    ctx = RunContext(cfg, out, RunLog(log_path, wall_offset=prior_wall),
                     torch.as_tensor(b.center, dtype=torch.float32, device=dev), b.extent)
    geo = scene.thermal if plan.use_thermal else scene.rgb
    ctx.log_line(f"stage 1: {scene.name}: {len(scene.rgb.frames)} RGB frames "
                 f"({len(scene.rgb.indices('test'))} test, {len(scene.rgb.indices('val'))} validation), "
                 f"{len(scene.thermal.frames) if scene.thermal else 0} thermal; geometry from {geo.name}; "
                 f"smoke={'on' if plan.use_smoke else 'off'} deform={'on' if plan.use_deform else 'off'} "
                 f"registered={report.registered} extent={b.extent:.3g}")
    thermal_scale = scene.thermal.scale if scene.thermal is not None and plan.use_thermal else None
    thermal_record = thermal_scale.record(scene.thermal.images) if thermal_scale is not None else None
    if thermal_record is not None:
        ctx.log_line(f"stage 1: thermal scale {thermal_scale.describe(thermal_record['crowded'])}")
    for note in report.notes:
        ctx.log_line(f"stage 1: {note}")
    if report.registration is not None:
        r = report.registration
        ctx.log_line(f"stage 1: registration: scale {r['scale']:.6g}, rotation {r['rotation_angle_deg']:.4g} deg "
                     f"about {np.round(r['rotation_axis'], 4).tolist()}, translation "
                     f"{np.round(r['translation'], 4).tolist()}, {r['inliers']}/{r['pairs']} inliers, centre rmse "
                     f"{r['centre_rmse']:.3g}, rotation rms {r['rotation_rms_deg']:.3g} deg, {r['geometry']} path")
    for note in plan.notes:
        ctx.log_line(f"stage 3: {note}")
    for warning in prep.warnings:
        ctx.log_line(warning.line())
    start_notes: list[str] = []

    def start_note(line: str) -> None:
        start_notes.append(line)
        ctx.log_line(line)

    init = _init_points(scene, report, geo, cfg.stage2.init_points, b,
                        numpy_stream(cfg.seed, f"init.points.{geo.name}"), start_note)
    deformable = cfg.mode == "deformable-3dgs"
    estimate = None
    smoke_colour: SmokeColourEstimate | None = None
    joined: TwoSurfaces | None = None
    if cfg.profile == "paper" and dev.type == "cpu":
        estimate = estimate_cpu_seconds(ctx, geo, init)
        ctx.log_line(f"profile paper on the CPU: {cfg.stage2.iterations} + {cfg.stage3.iterations} iterations, "
                     f"estimated at least {estimate / 3600:.1f} h (one measured iteration of "
                     f"{len(init)} Gaussians; the paper's schedule is meant for a GPU: --device cuda)")

    def s2_psnr(g: Any, deform: Any, background: Any, it: int) -> float | None:
        if not deformable:
            return None
        m = SceneModel(g, None, None, True, ctx.center, cfg.sh_degree, surface_deform=deform,
                       background_rgb=background)
        return heldout_psnr(m, scene, dev)

    t = time.perf_counter()
    # Flat thermal frames: the Stage 2 is RGB-only's, keyed as its own is.
    s2_sha = replace(cfg, mode="rgb-only").stage2_sha256() if plan.thermal_warning is not None else None
    s2 = train_stage2(ctx, geo, init, deformable=deformable, heldout_psnr=s2_psnr, sha=s2_sha)
    wall["stage2"] = time.perf_counter() - t
    ctx.log_line(f"stage 2: {s2.gaussians.n} Gaussians from {geo.name} in {wall['stage2']:.1f} s")
    t = time.perf_counter()
    if deformable:
        model = SceneModel(s2.gaussians, None, None, True, ctx.center, cfg.sh_degree, surface_deform=s2.deform,
                           background_rgb=s2.background)
        wall["stage3"] = 0.0
        ctx.log_line("stage 3: skipped (deformable-3dgs baseline has one deformable set)")
    else:
        smoke_pts = (_sample(scene.rgb, cfg.stage3.smoke_points, b, numpy_stream(cfg.seed, "init.smoke"), start_note,
                             "stage 3 smoke start") if plan.use_smoke else None)
        joins = cfg.stage3.surface_init == "by-smoke-colour" and plan.use_thermal
        rgb_views = views_of(scene.rgb, scene.rgb.indices("train"), dev)
        rgb_depth = (rendered_depth_prior(s2.gaussians, rgb_views, "rgb")
                     if plan.smoke_colour == "haze-lines" or plan.mask_floor != "all" or joins else None)
        if plan.smoke_colour == "haze-lines":
            smoke_colour = haze_line_smoke_colour(cfg, rgb_depth, scene.rgb)
            ctx.log_line(f"stage 3: smoke colour from haze lines: {smoke_colour.describe()}")
            note = plan.settle_colour(smoke_colour)
            if note:
                plan.notes.append(note)
                ctx.log_line(f"stage 3: {note}")
        rgb_share = 0.0
        if joins:
            rgb_share, note = surface_start(smoke_colour, plan.use_smoke)
            plan.notes.append(note)
            ctx.log_line(f"stage 3: {note}")
        if rgb_share > 0.0:
            t_rgb = time.perf_counter()
            rgb_init = _init_points(scene, report, scene.rgb, cfg.stage2.init_points, b,
                                    numpy_stream(cfg.seed, "init.points.rgb"), start_note)
            joined = join_surfaces(ctx, scene.rgb, rgb_init, s2, rgb_depth, rgb_share)
            wall["stage2_rgb"] = time.perf_counter() - t_rgb
            plan.notes.append(joined.describe())
            ctx.log_line(f"stage 3: {joined.describe()} (RGB Stage 2 in {wall['stage2_rgb']:.1f} s)")
        # The floor reads the geometry Stage 3 starts from: with two surfaces, the joined one.
        floor_depth = ((rendered_depth_prior(joined.surface, rgb_views, "rgb") if joined else rgb_depth)
                       if plan.mask_floor != "all" else None)
        if plan.mask_floor != "all":
            masked = scene.rgb.masks[scene.rgb.indices("train")] > 0.5
            if plan.mask_floor == "estimated-bound":
                plan.alpha_targets = alpha_targets(scene.rgb, floor_depth, cfg.loss.mask_alpha_floor, smoke_colour,
                                                   cfg.loss.mask_floor_meeting)
                pushed = masked & (plan.alpha_targets > 0)
                mean = float(plan.alpha_targets[pushed].mean()) if pushed.any() else 0.0
                where = ("the haze lines meet" if smoke_colour is not None and smoke_colour.meeting is not None else
                         "the haze lines do not meet: only points seen clear elsewhere, or the geometry does not "
                         "cover them")
                note = (f"mask term pushes the smoke alpha up to what the images prove on "
                        f"{100 * int(pushed.sum()) / max(int(masked.sum()), 1):.0f} % of the masked training pixels, "
                        f"mean target {mean:.2f} ({where}; loss.mask_floor_where=estimated-bound)")
            else:
                plan.floor_pixels = mask_floor_pixels(plan, scene.rgb, floor_depth, cfg.loss.mask_alpha_floor,
                                                      smoke_colour, cfg.loss.mask_floor_meeting)
                note = mask_floor_note(plan.mask_floor, cfg.loss.mask_floor_meeting, smoke_colour,
                                       float(plan.floor_pixels.sum()) / max(int(masked.sum()), 1))
            plan.notes.append(note)
            ctx.log_line(f"stage 3: {note}")
        model = build_scene_model(ctx, s2, plan, smoke_pts, scene.smoke_static,
                                  rgb_s2=joined.rgb if joined else None, surface=joined.surface if joined else None)
        prior = depth_prior_maps(cfg, plan, s2.gaussians, scene, dev)
        if prior is not None:
            ctx.log_line(f"stage 3: depth term at the {prior.camera} camera ({cfg.depth_prior} prior, "
                         f"{prior.maps.shape[0]} training views)")
        model = train_stage3(ctx, model, scene.rgb, scene.thermal, plan, prior,
                             heldout_psnr=lambda m, it: heldout_psnr(m, scene, dev))
        wall["stage3"] = time.perf_counter() - t - wall.get("stage2_rgb", 0.0)
        ctx.log_line(f"stage 3: {model.surface.n} surface + {model.smoke.n if model.smoke else 0} smoke "
                     f"Gaussians in {wall['stage3']:.1f} s")
    t = time.perf_counter()
    renders = write_renders(model, scene, out, dev)
    scores = score(renders, scene, cfg.lpips_net, cfg.lpips_weights or None, cfg.lpips_heads or None)
    validation = score_validation(model, scene, dev)
    write_test_figures(renders, scene, out, scores["per_image"], cfg.mode, plan.use_thermal)
    write_plys(model, out, cfg.smoke_ply_times)
    wall["eval"] = time.perf_counter() - t
    wall["total"] = time.perf_counter() - t_start
    m = scores["metrics"]
    shadowed = (f"; vs shadowed {m['psnr_shadowed']} and {m['psnr_input_shadowed']}"
                if m["psnr_shadowed"] is not None else "")
    ctx.log_line(f"eval: PSNR surface vs clean {m['psnr']}, smoky input vs clean {m['psnr_input']}{shadowed} "
                 f"in {wall['eval']:.1f} s")
    doc = _metrics_doc(prep, "ok")
    doc.update(scores)
    doc["validation"] = validation
    doc["surface_diagnostics"] = surface_diagnostics(renders, scene)
    doc["wall_time_s"] = {k: round(v, 3) for k, v in wall.items()}
    if estimate is not None:
        doc["wall_time_s"]["estimated_min"] = round(estimate, 3)
    doc["stages"] = {"registered": report.registered, "registration_rmse": report.registration_rmse,
                     "pose_noise": report.pose_noise, "geometry_modality": geo.name,
                     "smoke_gaussians": model.smoke.n if model.smoke is not None else 0,
                     "surface_gaussians": model.surface.n, "deformation": plan.use_deform,
                     "registration": report.registration, "masks": report.masks, "poses": scene.poses,
                     "smoke_colour": smoke_colour_record(plan, smoke_colour),
                     "surface_union": joined.record if joined else None,
                     "thermal_scale": thermal_record,
                     "start_points": report.start_points.record if report.start_points is not None else None,
                     "thermal_used": plan.use_thermal, "thermal_dropped": plan.thermal_dropped,
                     "loss_rise": {name: round(rise, 4) for name, rise in ctx.loss_rise.items()},
                     "stage3_plan": None if deformable else plan.record(),
                     "notes": list(report.notes) + start_notes + list(plan.notes)}
    write_json(out / "metrics.json", doc)
    return doc


def haze_line_smoke_colour(cfg: TrainConfig, depth: DepthPriorMaps, rgb: ModalityData) -> SmokeColourEstimate:
    """The smoke colour where the training RGB frames' observation lines meet, with Stage 2's
    geometry rendered as depth at each of those frames (``depth``) saying which pixels see the
    same point."""
    return estimate_smoke_colour(rgb.images[rgb.indices("train")], depth.maps.cpu().numpy(),
                                 depth.valid.cpu().numpy(), *rgb.cameras("train"),
                                 numpy_stream(cfg.seed, "stage1.haze-lines"),
                                 HazeLineSettings.of(cfg.stage3))


def by_meeting(rule: Callable[[np.ndarray | None], np.ndarray], estimate: SmokeColourEstimate | None,
               meeting: str) -> np.ndarray:
    """``rule`` (a per-pixel floor or target, given the point where the haze lines meet, or None) as
    ``loss.mask_floor_meeting`` reads the meeting: "present", with the point wherever enough of the
    lines meet; "trusted", the rule with the point and without it blended by the point's weight
    (``SmokeColourEstimate.meeting_weight``), so that no one line turns a whole run's floor."""
    if meeting == "present":
        return rule(None if estimate is None else estimate.meeting)
    w = 0.0 if estimate is None or estimate.colour is None else estimate.meeting_weight
    with_point = rule(estimate.colour).astype(np.float32) if w > 0.0 else 0.0
    without = rule(None).astype(np.float32) if w < 1.0 else 0.0
    return np.asarray(w * with_point + (1.0 - w) * without, dtype=np.float32)


def mask_floor_pixels(plan: Stage3Plan, rgb: ModalityData, depth: DepthPriorMaps, floor: float,
                      estimate: SmokeColourEstimate | None, meeting: str) -> np.ndarray:
    """The training frames' pixels where the mask floor acts (``smokeseer.train.mask_floor``), with
    Stage 3's starting geometry rendered as depth at the same cameras and, for ``estimated-meeting``,
    the point where the haze lines ``estimate`` meet (read as ``meeting`` says: ``by_meeting``); in
    [0, 1] where that blends two rules, else bool."""
    train = rgb.indices("train")
    maps, valid = depth.maps.cpu().numpy(), depth.valid.cpu().numpy()
    if plan.mask_floor == "never-clear":
        return never_seen_clear(rgb.masks[train], maps, valid, *rgb.cameras("train"))
    return by_meeting(lambda colour: estimated_dense(rgb.masks[train], rgb.images[train], maps, valid,
                                                     *rgb.cameras("train"), colour, floor), estimate, meeting)


def alpha_targets(rgb: ModalityData, depth: DepthPriorMaps, floor: float,
                  estimate: SmokeColourEstimate | None, meeting: str) -> np.ndarray:
    """The smoke alpha the mask term pushes each masked training pixel up to with
    ``loss.mask_floor_where=estimated-bound`` (``smokeseer.train.mask_floor.estimated_alpha_bound``);
    ``floor`` where the geometry does not cover the pixel; the meeting read as ``by_meeting``."""
    train = rgb.indices("train")
    maps, valid = depth.maps.cpu().numpy(), depth.valid.cpu().numpy()
    return by_meeting(lambda colour: estimated_alpha_bound(rgb.masks[train], rgb.images[train], maps, valid,
                                                           *rgb.cameras("train"), colour, floor), estimate, meeting)


def mask_floor_note(where: str, meeting: str, estimate: SmokeColourEstimate | None, share: float) -> str:
    """The log line of where the mask floor acts: ``share`` of the masked training pixels (a
    weighted share where ``by_meeting`` blends two rules), and what decided the rest."""
    if where == "never-clear":
        rest = "the rest are seen smoke-free from another training view"
    elif meeting == "trusted" and estimate is not None and estimate.colour is not None:
        rest = (f"the rule with the point where the haze lines meet, {np.round(estimate.colour, 3).tolist()}, at "
                f"weight {estimate.meeting_weight:.2f} and without it at the rest (loss.mask_floor_meeting=trusted)")
    elif meeting == "present" and estimate is not None and estimate.meeting is not None:
        rest = ("the rest are thinner smoke by the images (a clear view, or too far from where the haze lines "
                f"meet, {np.round(estimate.meeting, 3).tolist()})")
    else:
        rest = ("the haze lines do not meet, so the smoke reads thin: only points seen clear elsewhere and dense "
                "there, or the geometry does not cover them")
    return f"mask floor on {100 * share:.0f} % of the masked training pixels: {rest} (loss.mask_floor_where={where})"


def smoke_colour_record(plan: Stage3Plan, estimate: SmokeColourEstimate | None) -> dict[str, Any] | None:
    """metrics.json ``stages.smoke_colour``: where the smoke colour came from; None without smoke."""
    if plan.smoke_colour == "none":
        return None
    if estimate is None:
        return {"source": "learned", "haze_lines": None}
    return {"source": plan.smoke_colour,
            "haze_lines": {"colour": None if estimate.colour is None else [float(c) for c in estimate.colour],
                           "trust": plan.trust, "surface_trust": estimate.surface_trust,
                           "lines": estimate.lines, "points": estimate.points,
                           "meeting_fraction": estimate.meeting_fraction, "limits": estimate.reason or None}}


def depth_prior_maps(cfg: TrainConfig, plan: Stage3Plan, geometry: Any, scene: SceneData,
                     dev: torch.device) -> DepthPriorMaps | None:
    """The maps the plan's depth term compares with, at its camera's training views; None without one."""
    if plan.depth_prior is None:
        return None
    camera = plan.depth_camera
    mod = scene.thermal if camera == "thermal" else scene.rgb
    idx = mod.indices("train")
    if plan.depth_prior == "files":
        return file_depth_prior(torch.as_tensor(mod.inverse_depth[idx], device=dev), camera)
    if plan.depth_prior == "mono":
        return monocular_depth_prior(Path(cfg.mono_weights), torch.as_tensor(mod.images[idx], device=dev), camera)
    return rendered_depth_prior(geometry, views_of(mod, idx, dev), camera)
