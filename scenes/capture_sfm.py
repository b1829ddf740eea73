"""Pose a capture that brings only images: RGB by structure from motion, thermal from the rig.

``capture.json`` may hold the intrinsics (``intrinsics.rgb``, held fixed by SfM; estimated
without them), SfM settings (``sfm``), and the rig's RGB→thermal extrinsic (``rig``,
``scenes.rig.parse_rig``). The thermal camera's intrinsics are needed to pose its frames from the
rig (``intrinsics.thermal``). Without ``rig`` the rig rotation is estimated from SfM on the
thermal frames where they register (``scenes.rig.estimate_rig_rotation``), and the identity is
assumed, saying why, where they do not.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from contracts.errors import DatasetError
from contracts.imageio import read_png
from scenes.cameras import intrinsics
from scenes.images import all_or_none, gray, image01
from scenes.rig import RigExtrinsic, estimate_rig_rotation, parse_rig, thermal_from_rig
from scenes.scene import Frame
from scenes.sfm import SfmError, SfmSettings, cache_dir, run_sfm, stretched

INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy")


@dataclass
class SfmPoses:
    """The registered RGB frames (full-resolution intrinsics), their files, and the SfM record."""

    frames: list[Frame]
    files: list[Path]
    size: tuple[int, int]
    points: np.ndarray
    record: dict[str, Any]
    notes: list[str]


def image_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.glob("*.png") if not p.name.startswith("."))


def given_intrinsics(meta: dict[str, Any], modality: str, source: Path) -> np.ndarray | None:
    """``capture.json`` → ``intrinsics.MODALITY``: ``fl_x``, ``fl_y``, ``cx``, ``cy`` in pixels
    of the full-size frames (pixel centres at +0.5), or None."""
    block = meta.get("intrinsics", {})
    if not isinstance(block, dict):
        raise DatasetError(f"{source}: field 'intrinsics' must be an object")
    cam = block.get(modality)
    if cam is None:
        return None
    if not isinstance(cam, dict):
        raise DatasetError(f"{source}: field 'intrinsics.{modality}' must be an object")
    values = []
    for key in INTRINSIC_KEYS:
        v = cam.get(key)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v) or (key.startswith("fl") and v <= 0):
            raise DatasetError(f"{source}: field 'intrinsics.{modality}.{key}' must be a "
                               f"{'positive ' if key.startswith('fl') else ''}number")
        values.append(float(v))
    return intrinsics(*values)


def sfm_settings(meta: dict[str, Any], source: Path) -> SfmSettings:
    """``capture.json`` → ``sfm``: overrides of ``SfmSettings`` fields, each checked."""
    block = meta.get("sfm", {})
    if not isinstance(block, dict):
        raise DatasetError(f"{source}: field 'sfm' must be an object")
    try:
        return SfmSettings.from_overrides(block)
    except ValueError as exc:
        raise DatasetError(f"{source}: {exc}") from None


def pose_rgb_by_sfm(path: Path, meta: dict[str, Any], source: Path, test_every: int) -> SfmPoses:
    """SfM on ``rgb/images/*.png`` with ``rgb/masks/`` (when present) excluding smoke pixels.
    Frames that do not register are left out and named in a note; too few stops the run."""
    files = image_files(path / "rgb" / "images")
    names = [p.stem for p in files]
    images = [read_png(p) for p in files]
    sizes = {a.shape[:2] for a in images}
    if len(sizes) != 1:
        raise DatasetError(f"{path / 'rgb' / 'images'}: frames differ in size ({sorted(sizes)}); one RGB camera is assumed")
    notes: list[str] = []
    mask_files = [path / "rgb" / "masks" / f"{n}.png" for n in names]
    masks = None
    if all_or_none(mask_files, "mask", "sfm: no smoke masks under rgb/masks/: features on smoke are not excluded "
                   "(bundle adjustment must reject them as outliers)", notes):
        masks = [gray(image01(read_png(p))) > 0.5 for p in mask_files]
        for p, m, a in zip(mask_files, masks, images):
            if m.shape != a.shape[:2]:
                raise DatasetError(f"{p}: mask is {m.shape[1]}x{m.shape[0]}, its frame {a.shape[1]}x{a.shape[0]}")
    K = given_intrinsics(meta, "rgb", source)
    res = run_sfm(names, images, masks, K, sfm_settings(meta, source), cache=cache_dir())
    h, w = images[0].shape[:2]
    frames, kept = [], []
    for i in np.nonzero(res.registered)[0]:
        j = len(frames)
        split = "test" if test_every > 0 and j % test_every == test_every // 2 else "train"
        frames.append(Frame(file_stem=names[i], viewmat=res.viewmats[i], K=res.K.copy(), width=w, height=h,
                            timestamp_s=float(i), time=0.0, split=split))
        kept.append(files[i])
    record = res.record()
    notes.append(f"poses from SfM (pycolmap): {res.describe()}")
    if record["unregistered"]:
        notes.append(f"sfm: left out {len(record['unregistered'])} RGB frames that did not register: "
                     f"{', '.join(record['unregistered'][:10])}{' ...' if len(record['unregistered']) > 10 else ''}")
    return SfmPoses(frames, kept, (h, w), res.points, record, notes)


def pose_thermal_by_rig(rgb: list[Frame], files: list[Path], stamps: dict[str, float], meta: dict[str, Any],
                        source: Path, size: tuple[int, int], where: Path) -> tuple[list[Frame], dict[str, Any], list[str]]:
    """Thermal frames posed from the RGB trajectory at their timestamps and the rig extrinsic;
    without ``rig`` its rotation is estimated from SfM on the thermal frames, where they register."""
    K = given_intrinsics(meta, "thermal", source)
    if K is None:
        raise DatasetError(f"{source}: field 'intrinsics.thermal' is needed to pose the thermal frames from the rig "
                           "(fl_x, fl_y, cx, cy)")
    names = [p.stem for p in files]
    rig = parse_rig(meta, source)
    times = np.array([stamps[n] for n in names])
    rgb_views, rgb_times = np.stack([f.viewmat for f in rgb]), np.array([f.timestamp_s for f in rgb])
    notes: list[str] = []
    record: dict[str, Any] = {"source": "rig", "extrinsic": "given"}
    if rig is None:
        rig, record["extrinsic"], notes = _estimated_rig(files, times, K, rgb_views, rgb_times, meta, source)
    try:
        views, rig_notes = thermal_from_rig(rgb_views, rgb_times, times, rig)
    except ValueError as exc:
        raise DatasetError(f"{where}: {exc}") from None
    record["lever_applied"] = rig is not None and rig.applies_lever
    h, w = size
    frames = [Frame(file_stem=n, viewmat=v, K=K.copy(), width=w, height=h, timestamp_s=float(t), time=0.0,
                    split="train") for n, v, t in zip(names, views, times)]
    return frames, record, [f"thermal: {n}" for n in notes + rig_notes]


def _estimated_rig(files: list[Path], times: np.ndarray, K: np.ndarray, rgb_views: np.ndarray, rgb_times: np.ndarray,
                   meta: dict[str, Any], source: Path) -> tuple[RigExtrinsic | None, str, list[str]]:
    """The rig rotation from thermal SfM (zero lever arm), or None (the identity is then assumed,
    and said) when the thermal frames do not register or their path cannot fix it."""
    settings = replace(sfm_settings(meta, source), min_registered=0.5)
    try:
        res = run_sfm([p.stem for p in files], stretched([read_png(p) for p in files]), None, K, settings,
                      cache=cache_dir(), what="thermal frames")
        est = estimate_rig_rotation(rgb_views, rgb_times, res.viewmats[res.registered], times[res.registered])
    except (SfmError, ValueError) as exc:
        return None, f"assumed (identity, zero lever arm): not estimated, {exc}", [f"rig not estimated: {exc}"]
    angle = float(np.degrees(np.arccos(np.clip((np.trace(est.rotation) - 1.0) / 2.0, -1.0, 1.0))))
    note = (f"rig rotation estimated from SfM on the thermal frames ({int(res.registered.sum())} of {len(files)} "
            f"registered): {angle:.2f} deg from the identity, frames agree within a median {est.residual_deg:.2f} deg; "
            "no lever arm (not estimated), and on an orbit a sideways lever tilts this estimate by about "
            "atan(lever / radius)")
    return RigExtrinsic(est.rotation, np.zeros(3)), f"estimated (thermal SfM, {angle:.2f} deg)", [note]
