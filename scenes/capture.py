"""Read our capture layout (docs/real-captures.md): RGB frames, everything else optional.

Poses per modality come from ``transforms_MODALITY.json`` or a COLMAP text model under
``MODALITY/sparse/``; ``MODALITY/timestamps.csv`` overrides any timestamps the poses carry.
RGB frames without poses are posed by structure from motion, and thermal frames without poses
then from the rig (``scenes.capture_sfm``).
"""
from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from contracts.dataset_format import load_json, transforms_name
from contracts.errors import DatasetError
from contracts.imageio import read_png
from scenes.capture_sfm import image_files, pose_rgb_by_sfm, pose_thermal_by_rig
from scenes.colmap_text import read_colmap_cameras, read_colmap_images, read_colmap_points
from scenes.images import box_downscale, check_finite, check_size, gray, load_masks, rgb01, thermal_images, working_factor
from scenes.scene import Frame, ModalityData, SceneData, set_times
from scenes.thermal_scale import LINEAR_SCALE, ThermalScaleSpec
from scenes.transforms import frames_from_transforms, read_capture_transforms

CAPTURE_FILE = "capture.json"
IMAGES = "images"
SPARSE = "sparse"


def is_capture(path: Path) -> bool:
    """What marks our capture layout: ``capture.json``, RGB frames under ``rgb/images/``, or RGB
    poses that name their image files (``file_path``) or come from a COLMAP text model."""
    if (path / CAPTURE_FILE).is_file() or (path / "rgb" / IMAGES).is_dir():
        return True
    if (path / "rgb" / SPARSE / "images.txt").is_file():
        return True
    transforms = path / transforms_name("rgb")
    if not transforms.is_file():
        return False
    frames = load_json(transforms).get("frames")
    return isinstance(frames, list) and any(isinstance(fr, dict) and "file_path" in fr for fr in frames)


def load_capture(path: Path, max_width: int, thermal_scale: ThermalScaleSpec) -> SceneData:
    meta = load_json(path / CAPTURE_FILE) if (path / CAPTURE_FILE).exists() else {}
    smoke = meta.get("smoke", {}) if isinstance(meta.get("smoke", {}), dict) else {}
    test_every = int(meta.get("test_every", 8))
    notes: list[str] = []
    poses: dict[str, Any] | None = None
    points = None
    rgb = _modality(path, "rgb", max_width, test_every, notes, thermal_scale)
    if rgb is None:
        if not image_files(path / "rgb" / IMAGES):
            raise DatasetError(f"{path}: no RGB poses (need {transforms_name('rgb')} or rgb/{SPARSE}/images.txt) "
                               f"and no rgb/{IMAGES}/*.png to pose by structure from motion")
        rgb, points, poses = _rgb_by_sfm(path, meta, max_width, test_every, notes)
    thermal = _modality(path, "thermal", max_width, 0, notes, thermal_scale)
    if thermal is None and poses is not None and image_files(path / "thermal" / IMAGES):
        thermal, poses["thermal"] = _thermal_by_rig(path, meta, rgb, max_width, notes, thermal_scale)
    set_times(rgb, thermal, meta.get("duration_s"))
    pts_file = path / "rgb" / SPARSE / "points3D.txt"
    if pts_file.exists():
        points = read_colmap_points(pts_file)
    return SceneData(
        name=str(meta.get("scene", path.name)), path=path.resolve(), rgb=rgb, thermal=thermal,
        smoke_present=bool(smoke.get("present", True)), smoke_static=bool(smoke.get("static", False)),
        mask_threshold=float(smoke.get("mask_threshold", 0.5)), synthetic=False,
        init_points=points, meta=meta, notes=notes, poses=poses)


def _rgb_by_sfm(path: Path, meta: dict[str, Any], max_width: int, test_every: int,
                notes: list[str]) -> tuple[ModalityData, np.ndarray, dict[str, Any]]:
    """RGB frames posed by SfM, at the working resolution, with their timestamps."""
    sfm = pose_rgb_by_sfm(path, meta, path / CAPTURE_FILE, test_every)
    notes += sfm.notes
    h, w = sfm.size
    factor = working_factor(w, max_width)
    frames = [_scaled(f, factor) for f in sfm.frames]
    _apply_timestamps(path, "rgb", frames, False, notes)
    rgb = _read_images(path, "rgb", frames, sfm.files, [(h, w)] * len(frames), factor,
                       f"the first frame, {sfm.files[0].name}", notes, LINEAR_SCALE)
    return rgb, sfm.points, {"rgb": sfm.record}


def _thermal_by_rig(path: Path, meta: dict[str, Any], rgb: ModalityData, max_width: int, notes: list[str],
                    thermal_scale: ThermalScaleSpec) -> tuple[ModalityData, dict[str, Any]]:
    """Thermal frames posed from the SfM trajectory; both cameras need real timestamps."""
    if meta.get("pose_frames") == "separate":
        raise DatasetError(f"{path / CAPTURE_FILE}: field 'pose_frames' is 'separate', but the thermal frames have no "
                           "poses of their own: the rig poses them in the RGB frame (use 'shared' or leave it out)")
    for modality in ("rgb", "thermal"):  # the RGB ones are already on the frames
        tfile = path / modality / "timestamps.csv"
        if not tfile.is_file():
            raise DatasetError(f"{tfile}: missing; posing thermal frames from the rig needs the timestamps of both cameras")
    stamps = read_timestamps(path / "thermal" / "timestamps.csv")
    files = image_files(path / "thermal" / IMAGES)
    for p in files:
        if p.stem not in stamps:
            raise DatasetError(f"{path / 'thermal' / 'timestamps.csv'}: no row for frame {p.stem!r}")
    h, w = read_png(files[0]).shape[:2]
    frames, record, rig_notes = pose_thermal_by_rig(rgb.frames, files, stamps, meta, path / CAPTURE_FILE,
                                                    (h, w), path / "thermal" / "timestamps.csv")
    notes += rig_notes
    factor = working_factor(w, max_width)
    frames = [_scaled(f, factor) for f in frames]
    return _read_images(path, "thermal", frames, files, [(h, w)] * len(frames), factor,
                        f"the first frame, {files[0].name}", notes, thermal_scale), record


def _scaled(frame: Frame, factor: int) -> Frame:
    k = frame.K.copy()
    k[:2] /= factor
    return replace(frame, K=k, width=frame.width // factor, height=frame.height // factor)


def _modality(path: Path, modality: str, max_width: int, test_every: int, notes: list[str],
              thermal_scale: ThermalScaleSpec) -> ModalityData | None:
    tpath = path / transforms_name(modality)
    colmap = path / modality / SPARSE
    if tpath.exists():
        data, raw = read_capture_transforms(tpath)
        factor = working_factor(int(data["w"]), max_width)
        frames = frames_from_transforms(tpath, data, raw, factor, test_every if modality == "rgb" else 0)
        if modality == "thermal":
            for f in frames:
                f.split = "train"
        files = [path / str(fr.get("file_path", f"{modality}/{IMAGES}/{f.file_stem}.png"))
                 for fr, f in zip(raw, frames)]
        sizes = [(int(data["h"]), int(data["w"]))] * len(frames)
        source = tpath.name
        from_poses = all("timestamp_s" in fr for fr in raw)
    elif (colmap / "images.txt").exists():
        frames, files, sizes, factor = _frames_from_colmap(path, modality, max_width, test_every)
        source = "cameras.txt"
        from_poses = False
    else:
        return None
    _apply_timestamps(path, modality, frames, from_poses, notes)
    return _read_images(path, modality, frames, files, sizes, factor, source, notes, thermal_scale)


def _read_images(path: Path, modality: str, frames: list[Frame], files: list[Path], sizes: list[tuple[int, int]],
                 factor: int, source: str, notes: list[str], thermal_scale: ThermalScaleSpec) -> ModalityData:
    """The frames' images (and RGB masks) at the working resolution, each checked against its size."""
    imgs = []
    for fpath, (h, w) in zip(files, sizes):
        if not fpath.suffix:
            fpath = fpath.with_suffix(".png")
        arr = read_png(fpath)
        check_size(arr, fpath, h, w, source)
        imgs.append(arr)
    masks = None
    if modality == "rgb":
        images = np.stack([box_downscale(rgb01(a, p), factor) for a, p in zip(imgs, files)])
        scale = None
        masks = load_masks([path / "rgb" / "masks" / f"{f.file_stem}.png" for f in frames], factor,
                           f"{path / 'rgb' / 'masks'}", notes)
    else:
        images, scale = thermal_images(np.stack([gray(a) for a in imgs]), factor, thermal_scale)
    check_finite(images, path / modality)
    return ModalityData(name=modality, frames=frames, images=images.astype(np.float32),
                        masks=masks, scale=scale)


def read_timestamps(tfile: Path) -> dict[str, float]:
    """``name,timestamp_s`` rows → {stem: seconds}; a bad row names the file, line and value."""
    out: dict[str, float] = {}
    with tfile.open(newline="") as fh:
        for row_no, row in enumerate(csv.reader(fh), start=1):
            if not row or not row[0].strip() or row[0].startswith("#") or row[0].strip() == "name":
                continue
            if len(row) < 2:
                raise DatasetError(f"{tfile}: line {row_no}: expected 'name,timestamp_s', got {','.join(row)!r}")
            try:
                value = float(row[1])
            except ValueError:
                raise DatasetError(f"{tfile}: line {row_no}: timestamp {row[1]!r} is not a number") from None
            if not math.isfinite(value):
                raise DatasetError(f"{tfile}: line {row_no}: timestamp {row[1]!r} is not finite")
            stem = Path(row[0].strip()).stem
            if stem in out:
                raise DatasetError(f"{tfile}: line {row_no}: {row[0]!r} is listed twice")
            out[stem] = value
    return out


def _apply_timestamps(path: Path, modality: str, frames: list[Frame], from_poses: bool,
                      notes: list[str]) -> None:
    """Honour ``MODALITY/timestamps.csv`` whatever the pose source; without any timestamps say
    that the frame index stands in for time."""
    tfile = path / modality / "timestamps.csv"
    if tfile.exists():
        stamps = read_timestamps(tfile)
        for f in frames:
            if f.file_stem not in stamps:
                raise DatasetError(f"{tfile}: no row for frame {f.file_stem!r}")
            f.timestamp_s = stamps[f.file_stem]
        return
    if not from_poses:
        notes.append(f"{modality}: no timestamps (no {tfile.name}, none in the poses); "
                     "frame index used as timestamp in seconds")


def _frames_from_colmap(path: Path, modality: str, max_width: int,
                        test_every: int) -> tuple[list[Frame], list[Path], list[tuple[int, int]], int]:
    sparse = path / modality / SPARSE
    cams = read_colmap_cameras(sparse / "cameras.txt")
    images = read_colmap_images(sparse / "images.txt")
    widths = {w for w, _, _ in cams.values()}
    factor = working_factor(max(widths), max_width)
    frames, files, sizes = [], [], []
    for i, (name, cid, v) in enumerate(images):
        if cid not in cams:
            raise DatasetError(f"{sparse / 'images.txt'}: {name} uses unknown camera {cid}")
        w, h, k = cams[cid]
        kk = k.copy()
        kk[:2] /= factor
        split = "test" if test_every > 0 and i % test_every == test_every // 2 else "train"
        stem = Path(name).stem
        frames.append(Frame(file_stem=stem, viewmat=v, K=kk, width=w // factor, height=h // factor,
                            timestamp_s=float(i), time=0.0, split=split))
        files.append(path / modality / IMAGES / name)
        sizes.append((h, w))
    return frames, files, sizes, factor
