"""Held-out evaluation and run outputs: renders, metrics against the smoke-free ground truth,
and PLY exports. Scoring uses contracts.metrics, the one implementation of every metric; LPIPS
is scored here too, from the float renders at the training resolution against the ground truth
loaded at that same resolution, so no other code re-scores saved PNGs."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import torch
from PIL import Image

from contracts.atomic import atomic_path
from contracts.metrics import depth_errors, load_lpips, mask_iou, psnr, psnr_where, ssim_3dgs
from contracts.results_format import SHADOWED_METRIC_KEYS
from scenes.scene import SceneData
from smokeseer.model.scene import SceneModel, View, make_view, sh_coeffs, smoke_sh
from smokeseer.raster import GaussianPly, write_ply


@dataclass
class TestRenders:
    """Surface-only renders (the de-smoked prediction) and smoke alpha for each test view, with the
    surface's own alpha and the surface rendered on black (``surface_diagnostics``)."""

    stems: list[str]
    surface: list[np.ndarray]
    surface_depth: list[np.ndarray]
    smoke_alpha: list[np.ndarray | None]
    surface_alpha: list[np.ndarray]
    surface_on_black: list[np.ndarray]


OPAQUE_SURFACE = 0.9
"""A test pixel whose surface alpha is under this shows the background through the surface."""


def split_views(scene: SceneData, device: torch.device, split: str = "test") -> tuple[list[int], list[View]]:
    idx = scene.rgb.indices(split)
    fr = scene.rgb.frames
    return idx, [make_view(fr[i].viewmat, fr[i].K, fr[i].width, fr[i].height, fr[i].time, device) for i in idx]


def _surface_images(model: SceneModel, views: list[View]) -> list[np.ndarray]:
    with torch.no_grad():
        return [model.render_rgb(v, smoke=False).colors[0].clamp(0, 1).cpu().numpy() for v in views]


def split_psnr(model: SceneModel, scene: SceneData, device: torch.device, split: str) -> float | None:
    """Mean PSNR of surface-only renders against the clean images of one RGB split."""
    idx, views = split_views(scene, device, split)
    if scene.rgb.clean is None or not idx:
        return None
    return float(np.mean([psnr(img, scene.rgb.clean[i]) for i, img in zip(idx, _surface_images(model, views))]))


def heldout_psnr(model: SceneModel, scene: SceneData, device: torch.device) -> dict[str, float | None]:
    """Validation and test PSNR for the run log. Only the validation column may steer choices;
    the test column is logged for the error-against-time curves."""
    return {"val_psnr": split_psnr(model, scene, device, "val"),
            "test_psnr": split_psnr(model, scene, device, "test")}


def score_validation(model: SceneModel, scene: SceneData, device: torch.device) -> dict[str, Any] | None:
    """PSNR and SSIM of the surface-only renders on the validation views (metrics.json
    ``validation``); None without validation views or clean ground truth."""
    idx, views = split_views(scene, device, "val")
    if scene.rgb.clean is None or not idx:
        return None
    imgs = _surface_images(model, views)
    gts = [scene.rgb.clean[i].astype(np.float64) for i in idx]
    return {"views": len(idx),
            "psnr": float(np.mean([psnr(a, b) for a, b in zip(imgs, gts)])),
            "ssim": float(np.mean([ssim_3dgs(a, b) for a, b in zip(imgs, gts)])),
            "psnr_input": float(np.mean([psnr(scene.rgb.images[i], g) for i, g in zip(idx, gts)]))}


def _save_png8(path: Path, img: np.ndarray) -> None:
    arr = np.clip(np.round(np.clip(img, 0.0, 1.0) * 255.0), 0, 255).astype(np.uint8)
    with atomic_path(path) as tmp:
        Image.fromarray(arr[..., 0] if arr.shape[-1] == 1 else arr).save(tmp, format="PNG")


def _save_png16(path: Path, counts: np.ndarray) -> None:
    arr = np.clip(np.round(counts), 0, 65535).astype(np.uint16)
    with atomic_path(path) as tmp:
        Image.fromarray(arr).save(tmp, format="PNG")


def thermal_test_view(scene: SceneData, i: int, device: torch.device) -> View | None:
    """The thermal camera model at an RGB test frame: the RGB pose (the cameras are co-located
    on the rig) with the thermal intrinsics and resolution, at the frame's time."""
    if scene.thermal is None:
        return None
    f = scene.rgb.frames[i]
    t0 = scene.thermal.frames[0]
    return make_view(f.viewmat, t0.K, t0.width, t0.height, f.time, device)


def write_renders(model: SceneModel, scene: SceneData, out: Path, device: torch.device) -> TestRenders:
    """renders/{composite,surface,smoke,thermal}/NNNN.png for every test view."""
    idx, views = split_views(scene, device)
    res = TestRenders([], [], [], [], [], [])
    scale = scene.thermal.scale if scene.thermal is not None else None
    with torch.no_grad():
        for i, v in zip(idx, views):
            stem = scene.rgb.frames[i].file_stem
            comp = model.render_rgb(v)
            surf = model.render_rgb(v, smoke=False) if model.smoke is not None else comp
            _save_png8(out / "renders" / "composite" / f"{stem}.png", comp.colors[0].cpu().numpy())
            surf_img = surf.colors[0].clamp(0, 1).cpu().numpy()
            _save_png8(out / "renders" / "surface" / f"{stem}.png", surf_img)
            if model.smoke is not None:
                smoke = model.render_rgb(v, surface=False).colors[0].cpu().numpy()
            else:
                smoke = np.zeros_like(surf_img)
            _save_png8(out / "renders" / "smoke" / f"{stem}.png", smoke)
            tv = thermal_test_view(scene, i, device)
            if tv is not None and "thermal" in model.surface and scale is not None:
                th = model.render_thermal(tv).colors[0, ..., 0].cpu().numpy()
                _save_png16(out / "renders" / "thermal" / f"{stem}.png", scale.invert(th))
            res.stems.append(stem)
            res.surface.append(surf_img)
            res.surface_depth.append(surf.depths[0, ..., 0].cpu().numpy())
            res.smoke_alpha.append(comp.subset_alphas[0, ..., 0].cpu().numpy()
                                   if comp.subset_alphas is not None else None)
            res.surface_alpha.append(surf.alphas[0, ..., 0].cpu().numpy())
            black = model.render_rgb(v, smoke=False, background=False) if model.background_rgb is not None else surf
            res.surface_on_black.append(black.colors[0].clamp(0, 1).cpu().numpy())
    return res


def masked_colour_bias(
        pairs: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[list[float] | None, int]:
    """The colour cast a de-smoked surface keeps: the mean signed error per channel (render − clean)
    over the pixels each view's smoke mask marks (> 0.5), from (render, clean, mask) triples, and the
    number of those pixels; None where no mask marks any. The one formula behind metrics.json
    ``surface_diagnostics.colour_bias_smoky`` and ``benchmarks/colour_bias.py``."""
    total, pixels = np.zeros(3), 0
    for render, clean, mask in pairs:
        inside = mask > 0.5
        total += (np.asarray(render, dtype=np.float64)[inside] - np.asarray(clean, dtype=np.float64)[inside]).sum(axis=0)
        pixels += int(inside.sum())
    return ((total / pixels).tolist() if pixels else None), pixels


def _mean_or_none(values: list[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def surface_diagnostics(renders: TestRenders, scene: SceneData) -> dict[str, Any] | None:
    """How the de-smoked surface goes wrong, beyond its PSNR (metrics.json ``surface_diagnostics``):
    its colour cast on the test pixels the smoke mask marks (``masked_colour_bias``), the share of
    test pixels where the surface is not opaque (alpha under ``OPAQUE_SURFACE``: the environment
    shows through), and, on the pixels where the clean depth has a surface, the PSNR of the surface
    render and of the surface rendered on black: their gap is how much of the score the environment
    seen through the surface carries. The sky, where black is wrong by construction, is left out.
    None without clean ground truth; the surface-pixel PSNRs are None without clean depth."""
    rgb = scene.rgb
    idx = rgb.indices("test")
    if rgb.clean is None or not idx:
        return None
    bias, smoky = (None, 0) if rgb.masks is None else masked_colour_bias(
        (renders.surface[k], rgb.clean[i], rgb.masks[i]) for k, i in enumerate(idx))
    on_surface = {key: None if rgb.depth is None else _mean_or_none(
                      [psnr_where(images[k], rgb.clean[i], rgb.depth[i] > 0) for k, i in enumerate(idx)])
                  for key, images in (("psnr_surface_pixels", renders.surface),
                                      ("psnr_surface_pixels_on_black", renders.surface_on_black))}
    return {"colour_bias_smoky": bias, "smoky_pixels": smoky,
            "colour_bias_smoky_max": max(abs(b) for b in bias) if bias else None,
            "surface_alpha_under_0_9": float(np.mean([(a < OPAQUE_SURFACE).mean() for a in renders.surface_alpha])),
            **on_surface}


def score(renders: TestRenders, scene: SceneData, lpips_net: str = "alex", lpips_weights: str | None = None,
          lpips_heads: str | None = None) -> dict[str, Any]:
    """metrics + per_image for metrics.json; metrics are None where the data has no GT. With the
    shadowed ground truth (the frames under the smoke's shadow, no smoke in view), the render and
    the smoky input are scored against it too (``*_shadowed``)."""
    idx = scene.rgb.indices("test")
    rgb = scene.rgb
    per_image: list[dict[str, Any]] = []
    metrics: dict[str, Any] = {"psnr": None, "ssim": None, "lpips": None, "lpips_status": "",
                               "psnr_input": None, "depth_absrel": None, "depth_rmse": None,
                               "mask_iou": None, **dict.fromkeys(SHADOWED_METRIC_KEYS)}
    if not idx:
        metrics["lpips_status"] = "skipped: no test views"
        return {"metrics": metrics, "per_image": per_image}
    scorer, status = load_lpips(lpips_weights, lpips_net, lpips_heads)
    metrics["lpips_status"] = status
    if rgb.clean is None:
        metrics["lpips_status"] = "skipped: no clean ground truth"
        return {"metrics": metrics, "per_image": per_image}
    lp_vals, ious, absrel, rmse = [], [], [], []
    for k, i in enumerate(idx):
        pred = renders.surface[k]
        gt = rgb.clean[i].astype(np.float64)
        entry = {"file_stem": renders.stems[k], "psnr": psnr(pred, gt), "ssim": ssim_3dgs(pred, gt),
                 "psnr_input": psnr(rgb.images[i], gt)}
        if rgb.shadowed is not None:
            shadowed = rgb.shadowed[i].astype(np.float64)
            entry.update(psnr_shadowed=psnr(pred, shadowed), ssim_shadowed=ssim_3dgs(pred, shadowed),
                         psnr_input_shadowed=psnr(rgb.images[i], shadowed))
        if scorer is not None:
            try:
                entry["lpips"] = float(scorer(pred, gt))
            except ValueError as exc:  # e.g. views too small for the network's pooling
                scorer, metrics["lpips_status"] = None, f"skipped: {exc}"
                lp_vals = []
            else:
                lp_vals.append(entry["lpips"])
        per_image.append(entry)
        if rgb.depth is not None and np.any(rgb.depth[i] > 0):
            de = depth_errors(renders.surface_depth[k] * scene.score_depth_scale, rgb.depth[i])
            absrel.append(de["absrel"])
            rmse.append(de["rmse"])
        alpha = renders.smoke_alpha[k]
        if alpha is not None and rgb.masks is not None:
            iou = mask_iou(alpha > scene.mask_threshold, rgb.masks[i] > 0.5)
            if iou is not None:
                ious.append(iou)
    metrics["psnr"] = float(np.mean([e["psnr"] for e in per_image]))
    metrics["ssim"] = float(np.mean([e["ssim"] for e in per_image]))
    metrics["psnr_input"] = float(np.mean([e["psnr_input"] for e in per_image]))
    if rgb.shadowed is not None:
        for key in SHADOWED_METRIC_KEYS:
            metrics[key] = float(np.mean([e[key] for e in per_image]))
    metrics["lpips"] = float(np.mean(lp_vals)) if lp_vals else None
    metrics["depth_absrel"] = float(np.mean(absrel)) if absrel else None
    metrics["depth_rmse"] = float(np.mean(rmse)) if rmse else None
    metrics["mask_iou"] = float(np.mean(ious)) if ious else None
    for key, val in metrics.items():
        if isinstance(val, float) and not math.isfinite(val):
            raise ValueError(f"metrics.{key}: non-finite value {val}")
    return {"metrics": metrics, "per_image": per_image}


def _ply(means: torch.Tensor, quats: torch.Tensor, log_scales: torch.Tensor,
         opacity: torch.Tensor, sh: torch.Tensor) -> GaussianPly:
    p = opacity.clamp(1e-6, 1 - 1e-6)
    return GaussianPly(means=means.detach().cpu().numpy().astype(np.float32),
                       quats=quats.detach().cpu().numpy().astype(np.float32),
                       log_scales=log_scales.detach().cpu().numpy().astype(np.float32),
                       opacity_logits=torch.log(p / (1 - p)).detach().cpu().numpy().astype(np.float32),
                       sh=sh.detach().cpu().numpy().astype(np.float32))


def write_plys(model: SceneModel, out: Path, times: tuple[float, ...]) -> list[Path]:
    """ply/surface.ply (RGB SH, shared opacity; the deformable-3dgs baseline's at t = 0.5) and
    ply/smoke_tX.XX.ply per chosen time."""
    d = out / "ply"
    d.mkdir(parents=True, exist_ok=True)
    written = []
    s = model.surface
    with torch.no_grad():
        placed = model.surface_at(0.5)
        path = d / "surface.ply"
        write_ply(path, _ply(placed.means, placed.quats, placed.log_scales, torch.sigmoid(s["opacity"]),
                             sh_coeffs(s)))
        written.append(path)
        if model.smoke is not None:
            k = s["sh_dc"].shape[1] + s["sh_rest"].shape[1]
            for t in times:
                placed, o_rgb, _ = model.smoke_at(t)
                path = d / f"smoke_t{t:.2f}.ply"
                write_ply(path, _ply(placed.means, placed.quats, placed.log_scales, o_rgb,
                                     smoke_sh(model.smoke_colours(), k)))
                written.append(path)
    return written

