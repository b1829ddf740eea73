"""Read the two layouts of the official SmokeSeer code (cmu-ci-lab/SmokeSeer), so a dataset
prepared for it trains here unchanged.

Both are read by the official reader's own rules, so the two programs see the same frames:

- **Blender** (``transforms_train.json``): ``file_path`` + ".png", last two path parts kept;
  RGBA composited on black; ``NAME_gt.png`` beside a frame is its smoke-free truth; ``frame``
  is the normalised time; intrinsics from ``camera_angle_x`` with a centred principal point.
- **COLMAP** (``sparse/0/images.bin``): names with "thermal" are thermal, names containing
  "gt" are skipped, the digits of a name are its frame number; every 8th RGB image by sorted
  name is held out (the official ``--eval``).

``smokeseer_interop.json``, written by ``convert-dataset``, restores what the layouts cannot
hold (seconds, the smoke flags); without it the loader says what it assumed.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from contracts.dataset_format import check_pose, load_json, need_field
from contracts.errors import DatasetError
from contracts.imageio import image01, read_png
from scenes.cameras import c2w_gl_to_viewmat, intrinsics
from scenes.colmap_binary import read_cameras_bin, read_images_bin, read_points3d_bin
from scenes.images import box_downscale, gray, load_masks, rgba_on_black, thermal_images, working_factor
from scenes.official_depth import read_depth_files, reciprocal_or_zero
from scenes.scene import Frame, ModalityData, SceneData, set_times
from scenes.thermal_scale import LINEAR_SCALE, ThermalScaleSpec

SIDECAR = "smokeseer_interop.json"
OFFICIAL_TEST_EVERY = 8


def detect_official_layout(path: Path) -> str | None:
    """'smokeseer-blender', 'smokeseer-colmap', or None: the same files the official code tests."""
    if (path / "transforms_train.json").is_file():
        return "smokeseer-blender"
    if (path / "sparse" / "0" / "images.bin").is_file():
        return "smokeseer-colmap"
    return None


def load_official(path: Path, layout: str, max_width: int, thermal_scale: ThermalScaleSpec = LINEAR_SCALE) -> SceneData:
    sidecar = load_json(path / SIDECAR) if (path / SIDECAR).is_file() else {}
    notes: list[str] = [] if sidecar else [
        f"{path}: no {SIDECAR}; smoke assumed present and moving (set by the data under --stage1 estimate)"]
    if layout == "smokeseer-blender":
        rgb, thermal, points = _load_blender(path, max_width, sidecar, notes, thermal_scale)
    else:
        rgb, thermal, points = _load_colmap(path, max_width, sidecar, notes, thermal_scale)
    smoke = sidecar.get("smoke", {}) if isinstance(sidecar.get("smoke", {}), dict) else {}
    meta = {"layout": layout, **sidecar}
    return SceneData(
        name=str(sidecar.get("scene", path.name)), path=path.resolve(), rgb=rgb, thermal=thermal,
        smoke_present=bool(smoke.get("present", True)), smoke_static=bool(smoke.get("static", False)),
        mask_threshold=0.5, synthetic=rgb.clean is not None, init_points=points, meta=meta, notes=notes)


# ----------------------------------------------------------------------------- Blender layout

def official_image_path(file_path: str) -> str:
    """The official reader's rule: append '.png' and keep only the last two path parts."""
    return "/".join((file_path + ".png").split("/")[-2:])


def official_gt_path(rel: str) -> str:
    """The official reader's smoke-free truth beside a frame: split at the first dot."""
    parts = rel.split(".")
    return parts[0] + "_gt." + parts[1]


def _read_transforms(path: Path) -> tuple[float, list[dict[str, Any]]]:
    data = load_json(path)
    fovx = need_field(data, "camera_angle_x", path, (int, float))
    if not 0 < fovx < math.pi:
        raise DatasetError(f"{path}: field 'camera_angle_x' must be in (0, pi) radians, got {fovx}")
    frames = need_field(data, "frames", path, list)
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or not isinstance(fr.get("file_path"), str):
            raise DatasetError(f"{path}: frames[{i}].file_path is missing or not a string")
        if not isinstance(fr.get("frame"), (int, float)):
            raise DatasetError(f"{path}: frames[{i}].frame (normalised time) is missing or not a number")
        check_pose(fr.get("transform_matrix"), f"{path}: frames[{i}]")
    return float(fovx), frames


def _blender_modality(root: Path, files: list[tuple[str, str]], modality: str, max_width: int,
                      duration: float, notes: list[str],
                      thermal_scale: ThermalScaleSpec = LINEAR_SCALE) -> ModalityData | None:
    entries = []
    for name, split in files:
        tpath = root / name
        if not tpath.is_file():
            continue
        fovx, frames = _read_transforms(tpath)
        entries += [(fovx, fr, split, tpath) for fr in frames]
    if not entries:
        return None
    entries.sort(key=lambda e: (float(e[1]["frame"]), e[1]["file_path"]))
    raws, frames_out, cleans, mask_files = [], [], [], []
    factor = 1
    for fovx, fr, split, tpath in entries:
        rel = official_image_path(fr["file_path"])
        arr = read_png(root / rel)
        h, w = arr.shape[:2]
        factor = working_factor(w, max_width)
        f = 0.5 * w / math.tan(0.5 * fovx) / factor
        k = intrinsics(f, f, w / 2 / factor, h / 2 / factor)
        stem = Path(rel).stem
        t = float(fr["frame"])
        frames_out.append(Frame(file_stem=stem, viewmat=c2w_gl_to_viewmat(np.asarray(fr["transform_matrix"])),
                                K=k, width=w // factor, height=h // factor, timestamp_s=t * duration, time=t,
                                split=split if modality == "rgb" else "train"))
        raws.append(arr)
        gt = root / official_gt_path(rel)
        cleans.append(gt if gt.is_file() else None)
        mask_files.append(root / f"{Path(rel).parent}_mask" / f"{stem}.png")
    if len({(fr.width, fr.height) for fr in frames_out}) != 1:
        raise DatasetError(f"{root}: {modality} images differ in size")
    clean = None
    masks = None
    if modality == "rgb":
        images = np.stack([box_downscale(rgba_on_black(a), factor) for a in raws])
        if all(c is not None for c in cleans):
            clean = np.stack([box_downscale(rgba_on_black(read_png(c)), factor) for c in cleans])
        elif any(c is not None for c in cleans):
            raise DatasetError(f"{root}: only {sum(c is not None for c in cleans)} of {len(cleans)} RGB frames "
                               "have a NAME_gt.png")
        else:
            notes.append(f"{root}: no NAME_gt.png smoke-free truth; novel views are not scored")
        masks = load_masks(mask_files, factor, f"{root}/*_mask", notes)
        scale = None
    else:
        images, scale = thermal_images(np.stack([gray(rgba_on_black(a)) for a in raws]), factor, thermal_scale)
    return ModalityData(name=modality, frames=frames_out, images=images.astype(np.float32),
                        clean=None if clean is None else clean.astype(np.float32), masks=masks, scale=scale)


def _load_blender(path: Path, max_width: int, sidecar: dict[str, Any], notes: list[str],
                  thermal_scale: ThermalScaleSpec) -> tuple[ModalityData, ModalityData | None, np.ndarray | None]:
    if not (path / "transforms_test.json").is_file():
        raise DatasetError(f"{path / 'transforms_test.json'}: missing file (the official Blender layout has both "
                           "transforms_train.json and transforms_test.json)")
    duration = float(sidecar.get("duration_s", 1.0))
    rgb = _blender_modality(path, [("transforms_train.json", "train"), ("transforms_test.json", "test")],
                            "rgb", max_width, duration, notes)
    if rgb is None:
        raise DatasetError(f"{path}: transforms_train.json and transforms_test.json list no frames")
    thermal = _blender_modality(path, [("transforms_thermaltrain.json", "train"),
                                       ("transforms_thermaltest.json", "train")],
                                "thermal", max_width, duration, notes, thermal_scale)
    pts = path / "sparse_colmap" / "points3D.bin"
    points = read_points3d_bin(pts)[0] if pts.is_file() else None
    return rgb, thermal, points


# ----------------------------------------------------------------------------- COLMAP layout

def frame_number(name: str, where: Path) -> int:
    """The official rule: every digit of the name, concatenated."""
    digits = "".join(ch for ch in name if ch.isdigit())
    if not digits:
        raise DatasetError(f"{where}: image name {name!r} has no digits (the frame number is read from them)")
    return int(digits)


def _load_colmap(path: Path, max_width: int, sidecar: dict[str, Any], notes: list[str],
                 thermal_scale: ThermalScaleSpec) -> tuple[ModalityData, ModalityData | None, np.ndarray | None]:
    sparse = path / "sparse" / "0"
    cams = read_cameras_bin(sparse / "cameras.bin")
    images = read_images_bin(sparse / "images.bin")
    entries: dict[str, list[tuple[str, int, np.ndarray, np.ndarray, int, int]]] = {"rgb": [], "thermal": []}
    for im in images:
        base = Path(im.name).name
        stem = base.split(".")[0]
        if "gt" in stem:
            continue
        if im.camera_id not in cams:
            raise DatasetError(f"{sparse / 'images.bin'}: {im.name} uses unknown camera {im.camera_id}")
        cam = cams[im.camera_id]
        if cam.model == "PINHOLE":
            fx, fy, cx, cy = cam.params
        elif cam.model == "SIMPLE_PINHOLE":
            fx, cx, cy = cam.params
            fy = fx
        else:
            raise DatasetError(f"{sparse / 'cameras.bin'}: camera {cam.camera_id} model {cam.model} is not supported; "
                               "undistort to PINHOLE first (colmap image_undistorter)")
        k = intrinsics(fx, fy, cx, cy)
        modality = "thermal" if "thermal" in stem else "rgb"
        entries[modality].append((base, frame_number(base, sparse / "images.bin"), im.viewmat(), k,
                                  cam.width, cam.height))
    if not entries["rgb"]:
        raise DatasetError(f"{sparse / 'images.bin'}: no RGB images (names without 'thermal' and 'gt')")
    numbers = [e[1] for m in entries.values() for e in m]
    lo, hi = min(numbers), max(numbers)
    tick = float(sidecar.get("tick_s", 0.0))
    origin = float(sidecar.get("time_origin_s", 0.0))
    mods: dict[str, ModalityData | None] = {"rgb": None, "thermal": None}
    for modality, items in entries.items():
        if items:
            ordered = sorted(items, key=lambda e: e[0])
            mod = _colmap_modality(path, modality, ordered, max_width, notes, lo, hi, tick, origin, thermal_scale)
            _attach_depth(path, mod, [(e[5], e[4]) for e in ordered], max_width,
                          sidecar.get("images_depth") == "ground-truth", notes)
            mods[modality] = mod
    rgb, thermal = mods["rgb"], mods["thermal"]
    assert rgb is not None
    if tick > 0:
        set_times(rgb, thermal, sidecar.get("duration_s"))
    pts = sparse / "points3D.bin"
    points = read_points3d_bin(pts)[0] if pts.is_file() else None
    return rgb, thermal, points


def _attach_depth(path: Path, mod: ModalityData, sizes: list[tuple[int, int]], max_width: int,
                  truth: bool, notes: list[str]) -> None:
    """The layout's ``images_depth`` maps as the modality's depth prior; also its depth truth for
    scoring when the sidecar says they were written from ground truth."""
    if len(set(sizes)) != 1:
        raise DatasetError(f"{path / 'images'}: {mod.name} images differ in size")
    files = read_depth_files(path, [f.file_stem for f in mod.frames], sizes[0], working_factor(sizes[0][1], max_width),
                             mod.name, notes)
    if files is None:
        return
    mod.inverse_depth = files.inverse
    if truth:
        mod.depth = reciprocal_or_zero(files.inverse).astype(np.float32)


def _colmap_modality(path: Path, modality: str, items: list, max_width: int, notes: list[str],
                     lo: int, hi: int, tick: float, origin: float, thermal_scale: ThermalScaleSpec) -> ModalityData:
    factor = working_factor(max(e[4] for e in items), max_width)
    frames, raws, cleans = [], [], []
    for idx, (base, number, viewmat, k, w, h) in enumerate(items):
        arr = read_png(path / "images" / base)
        if arr.shape[0] != h or arr.shape[1] != w:
            raise DatasetError(f"{path / 'images' / base}: image is {arr.shape[1]}x{arr.shape[0]}, "
                               f"cameras.bin says {w}x{h}")
        kk = k.copy()
        kk[:2] /= factor
        split = "test" if modality == "rgb" and idx % OFFICIAL_TEST_EVERY == 0 else "train"
        frames.append(Frame(file_stem=base.split(".")[0], viewmat=viewmat, K=kk, width=w // factor,
                            height=h // factor, timestamp_s=number * tick + origin if tick > 0 else float(number),
                            time=(number - lo) / (hi - lo) if hi > lo else 0.0, split=split))
        raws.append(arr)
        stem, ext = base.split(".")[0], base.split(".")[1] if "." in base else "png"
        gt = path / "images" / f"{stem}_gt.{ext}"
        cleans.append(gt if gt.is_file() else None)
    clean = masks = scale = None
    if modality == "rgb":
        images = np.stack([box_downscale(rgba_on_black(a), factor) for a in raws])
        if all(c is not None for c in cleans):
            clean = np.stack([box_downscale(rgba_on_black(read_png(c)), factor) for c in cleans]).astype(np.float32)
        elif any(c is not None for c in cleans):
            raise DatasetError(f"{path / 'images'}: only {sum(c is not None for c in cleans)} of {len(cleans)} "
                               "RGB frames have a NAME_gt image")
        else:
            notes.append(f"{path / 'images'}: no NAME_gt smoke-free truth; novel views are not scored")
        masks = load_masks([path / "images_mask" / f"{f.file_stem}.png" for f in frames], factor,
                           f"{path / 'images_mask'}", notes)
    else:
        images, scale = thermal_images(np.stack([gray(image01(a)) for a in raws]), factor, thermal_scale)
    return ModalityData(name=modality, frames=frames, images=images.astype(np.float32), clean=clean, masks=masks,
                        scale=scale)
