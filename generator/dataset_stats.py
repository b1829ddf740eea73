"""`stats` of dataset.json: what the ground truth says about a scene (docs/dataset-format.md,
"Statistics"), computed from the dataset's own files, so the same numbers come out at generation
time and for a dataset made before a statistic existed (`generate-scene --update-stats DIR`).

How dense the smoke is where it is scored (optical depth, covered fraction, over the RGB test
views), how much of the test views no training view sees clear of it (the part no method can
recover from RGB alone), how much of the smoky input's error is the smoke's shadow, and how
warm objects stand out in thermal.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from contracts.atomic import write_json
from contracts.dataset_format import DATASET_FILE, PASS_FILES, SPEC_FILE, file_path, transforms_name, validate_dataset
from contracts.imageio import read_exr_channel, read_png
from contracts.unrecoverable import dataset_unrecoverable
from generator.optics.planck import band_radiance, brightness_temperature
from generator.postprocess import psnr_u8
from generator.spec import SceneSpec, load_spec_file

MAX_OPTICAL_DEPTH = math.log(255.0)
"""Opacity is clipped to 1 - 1/255 before its optical depth -ln(1 - alpha) is taken: behind
more smoke the surface changes an 8-bit pixel by under one level, so deeper smoke is not told
apart (and alpha = 1 would be infinite)."""
WARM_MATERIAL_K = 10.0
"""A material is warm (a person, an engine, a heater) when its temperature is at least this far
above the ambient temperature; the thermal contrast is that of such objects."""


def optical_depth(alpha: np.ndarray) -> np.ndarray:
    """-ln(1 - alpha) with alpha clipped to [0, 1 - 1/255] (``MAX_OPTICAL_DEPTH``). Alpha is the
    pixel's mean opacity, so this is the optical depth of its mean transmittance."""
    return -np.log1p(-np.clip(alpha.astype(np.float64), 0.0, 1.0 - math.exp(-MAX_OPTICAL_DEPTH)))


def _frames(root: Path, modality: str) -> list[dict[str, Any]]:
    return json.loads((root / transforms_name(modality)).read_text())["frames"]


def _alpha(root: Path, modality: str, stem: str) -> np.ndarray:
    return read_exr_channel(file_path(root, PASS_FILES[(modality, "smoke_alpha")][0], stem), "A")


def _rgb(root: Path, name: str, stem: str) -> np.ndarray:
    return read_png(file_path(root, PASS_FILES[("rgb", name)][0], stem))


def _mean_psnr(root: Path, a: str, b: str, stems: list[str]) -> float | None:
    """Mean over ``stems`` of the per-frame PSNR between RGB passes ``a`` and ``b`` (8-bit)."""
    finite = [v for v in (psnr_u8(_rgb(root, a, s), _rgb(root, b, s)) for s in stems) if np.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def nearest_in_time(frames: list[dict[str, Any]], times: list[float]) -> list[str]:
    """The file stem of the frame of ``frames`` nearest to each of ``times`` (normalised time)."""
    return [min(frames, key=lambda f: abs(f["time"] - t))["file_stem"] for t in times]


def _test_views(root: Path, passes: dict[str, list[str]], threshold: float) -> dict[str, Any]:
    """The statistics over the RGB test views (None where a pass they need is absent)."""
    tests = [f for f in _frames(root, "rgb") if f["split"] == "test"]
    stems = [f["file_stem"] for f in tests]
    rgb, thermal = set(passes.get("rgb", ())), set(passes.get("thermal", ()))
    out: dict[str, Any] = {"views": len(stems)}
    if "smoke_alpha" in rgb and stems:
        alpha = np.stack([_alpha(root, "rgb", s) for s in stems])
        tau, smoke = optical_depth(alpha), alpha > threshold
        out["rgb_optical_depth"] = float(tau.mean())
        out["rgb_optical_depth_in_smoke"] = float(tau[smoke].mean()) if smoke.any() else None
        out["smoke_fraction"] = float(smoke.mean())
    if "smoke_alpha" in thermal and stems:
        nearest = nearest_in_time(_frames(root, "thermal"), [f["time"] for f in tests])
        out["lwir_optical_depth"] = float(np.mean([optical_depth(_alpha(root, "thermal", s)).mean() for s in nearest]))
    if {"depth", "smoke_alpha"} <= rgb and stems:
        masks = dataset_unrecoverable(root)
        out["unrecoverable_share"] = float(np.mean([masks[s].mean() for s in stems]))
    for a, b in (("smoky", "clean"), ("smoky", "shadowed"), ("shadowed", "clean")):
        if {a, b} <= rgb and stems:
            out[f"psnr_{a}_vs_{b}"] = _mean_psnr(root, a, b, stems)
    return out


def thermal_contrast(root: Path, spec: SceneSpec, band_um: tuple[float, float]) -> dict[str, Any]:
    """Warm objects against their surroundings in the clean thermal frames (noise-free radiance),
    over every thermal frame's surface pixels (depth > 0; the sky is neither). Warm materials are
    those of the scene's objects at least ``WARM_MATERIAL_K`` above ambient; a pixel is warm when
    its brightness temperature (that of the blackbody with the same in-band radiance) lies above
    the split, halfway between ambient and the coolest warm material; the surroundings are the
    other surface pixels. The contrast is the difference of the two groups' median brightness
    temperatures: null when the scene has no warm material or none is in view."""
    ambient = spec.lights.ambient_temperature_k
    used = sorted({o.material for o in spec.objects if o.material is not None})
    warm_materials = [m for m in used if spec.materials[m].temperature_k >= ambient + WARM_MATERIAL_K]
    out: dict[str, Any] = {"warm_materials": warm_materials, "split_k": None, "warm_fraction": None,
                           "warm_k": None, "surroundings_k": None, "contrast_k": None}
    if not warm_materials:
        return out
    band = (band_um[0] * 1e-6, band_um[1] * 1e-6)
    split = ambient + 0.5 * (min(spec.materials[m].temperature_k for m in warm_materials) - ambient)
    radiance_file, depth_file = PASS_FILES[("thermal", "clean")][0], PASS_FILES[("thermal", "depth")][0]
    stems = [f["file_stem"] for f in _frames(root, "thermal")]
    radiance = np.concatenate([read_exr_channel(file_path(root, radiance_file, s), "L").ravel() for s in stems])
    surface = np.concatenate([read_exr_channel(file_path(root, depth_file, s), "Z").ravel() > 0 for s in stems])
    hot = radiance > float(band_radiance(split, band))
    warm, rest = radiance[surface & hot], radiance[surface & ~hot]
    out.update(split_k=split, warm_fraction=float(warm.size / max(int(surface.sum()), 1)))
    if warm.size and rest.size:
        # Brightness temperature is monotone in radiance: the median's temperature is the median temperature.
        out["warm_k"], out["surroundings_k"] = (float(brightness_temperature(np.median(v), band)) for v in (warm, rest))
        out["contrast_k"] = out["warm_k"] - out["surroundings_k"]
    return out


def scene_stats(root: Path, meta: dict[str, Any]) -> dict[str, Any]:
    """Every statistic the passes of the dataset at ``root`` allow; ``meta`` is its dataset.json
    (passes, mask threshold, the LWIR band), whose transforms and scene.yaml are already written.
    The flat keys are over all frames; ``test_views`` over the RGB test views."""
    passes = meta["passes"]
    threshold = float(meta["smoke"]["mask_threshold"])
    stats: dict[str, Any] = {}
    for modality in ("rgb", "thermal"):
        if "smoke_alpha" in passes.get(modality, ()):
            stems = [f["file_stem"] for f in _frames(root, modality)]
            masks = [read_png(file_path(root, PASS_FILES[(modality, "smoke_alpha")][1], s)) for s in stems]
            stats[f"{modality}_mean_smoke_alpha"] = float(np.mean([_alpha(root, modality, s).mean() for s in stems]))
            stats[f"{modality}_smoke_fraction"] = float(np.mean([(m > 0).mean() for m in masks]))
    if {"smoky", "clean"} <= set(passes.get("rgb", ())):
        every = [f["file_stem"] for f in _frames(root, "rgb")]
        stats["psnr_smoky_vs_clean"] = _mean_psnr(root, "smoky", "clean", every)
    if passes.get("rgb"):
        stats["test_views"] = _test_views(root, passes, threshold)
    if {"clean", "depth"} <= set(passes.get("thermal", ())):
        stats["thermal_contrast"] = thermal_contrast(root, load_spec_file(root / SPEC_FILE),
                                                     tuple(meta["optics"]["band_um"]))
    return stats


def update_stats(root: Path) -> dict[str, Any]:
    """Recompute the statistics of the finished dataset at ``root`` from its files and rewrite its
    dataset.json (atomically; every other file stays as it is). Returns the new statistics."""
    root = Path(root)
    meta = validate_dataset(root, check_images=False)
    meta["stats"] = scene_stats(root, meta)
    write_json(root / DATASET_FILE, meta)
    return meta["stats"]
