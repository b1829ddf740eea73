"""Load a generated dataset (docs/dataset-format.md) or a real capture (docs/real-captures.md).

Everything downstream sees one ``SceneData``: OpenCV world-to-camera matrices, intrinsics at
the working resolution, images as float arrays in [0, 1], and normalised times. Malformed
input raises ``DatasetError`` naming the file and the field, so the CLI can print one line.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from contracts.dataset_format import load_json, need_field
from contracts.errors import DatasetError
from smokeseer.cameras import c2w_gl_to_viewmat, intrinsics
from smokeseer.thermal_scale import LINEAR_SCALE, ThermalScale, ThermalScaleSpec

__all__ = ["DatasetError", "Frame", "ModalityData", "SceneData", "load_scene"]


@dataclass
class Frame:
    """One image's camera at the working resolution."""

    file_stem: str
    viewmat: np.ndarray
    K: np.ndarray
    width: int
    height: int
    timestamp_s: float
    time: float
    split: str


@dataclass
class ModalityData:
    """All frames of one camera; ``images`` is the training input (smoky), others optional."""

    name: str
    frames: list[Frame]
    images: np.ndarray
    clean: np.ndarray | None = None
    masks: np.ndarray | None = None
    depth: np.ndarray | None = None
    scale: ThermalScale | None = None
    """Thermal only: the dataset's curve from raw values to ``images`` (smokeseer.thermal_scale)."""
    inverse_depth: np.ndarray | None = None
    """A depth prior the layout carries (the official ``images_depth``): inverse depth in the
    model's units, 0 where there is none. Truth for scoring only if the layout says so."""

    def indices(self, split: str) -> list[int]:
        return [i for i, f in enumerate(self.frames) if f.split == split]

    def cameras(self, split: str) -> tuple[np.ndarray, np.ndarray]:
        """The split's world-to-camera matrices (N, 4, 4) and intrinsics (N, 3, 3), in ``indices`` order."""
        frames = [self.frames[i] for i in self.indices(split)]
        return np.stack([f.viewmat for f in frames]), np.stack([f.K for f in frames])

    @property
    def channels(self) -> int:
        return int(self.images.shape[-1])


@dataclass
class SceneData:
    """A scene ready for training: RGB always, thermal when the capture has it."""

    name: str
    path: Path
    rgb: ModalityData
    thermal: ModalityData | None
    smoke_present: bool
    smoke_static: bool
    mask_threshold: float
    synthetic: bool
    init_points: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    """What the loader assumed or left out (no masks, no timestamps, ...): logged and written
    to metrics.json so a substitution is never silent."""


def png_bit_depth(path: Path) -> int:
    """Bits per sample from the PNG header (IHDR byte 24): how raw values are scaled to [0, 1]."""
    with path.open("rb") as fh:
        head = fh.read(25)
    if len(head) < 25 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        raise DatasetError(f"{path}: not a PNG file (no IHDR header)")
    return int(head[24])


def read_png(path: Path) -> np.ndarray:
    """PNG as an array with its stored integer type: uint8, or uint16 for 16-bit grey.

    Pillow reads 16-bit colour PNGs as 8-bit RGB, so the dtype, not the values, says which
    full scale applies (``image01``); a dark 16-bit frame is never mistaken for an 8-bit one.
    """
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    try:
        with Image.open(path) as im:
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                if path.suffix.lower() == ".png" and png_bit_depth(path) != 16:
                    raise DatasetError(f"{path}: {png_bit_depth(path)}-bit integer PNG; expected 8- or 16-bit")
                return np.asarray(im).astype(np.uint16)
            if im.mode not in ("L", "RGB", "RGBA", "LA"):
                im = im.convert("RGB")
            return np.asarray(im).astype(np.uint8)
    except OSError as exc:
        raise DatasetError(f"{path}: unreadable image ({exc})") from exc


def image01(arr: np.ndarray) -> np.ndarray:
    """Integer image to float64 in [0, 1] by its type's full scale (8- or 16-bit)."""
    if arr.dtype == np.uint16:
        return arr.astype(np.float64) / 65535.0
    if arr.dtype == np.uint8:
        return arr.astype(np.float64) / 255.0
    raise TypeError(f"image01: expected uint8 or uint16, got {arr.dtype}")


def read_exr(path: Path, channel: str) -> np.ndarray:
    """One float channel of an EXR file."""
    import OpenEXR

    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    try:
        channels = OpenEXR.File(str(path)).channels()
    except Exception as exc:  # OpenEXR raises plain Exception subclasses for bad files
        raise DatasetError(f"{path}: unreadable EXR ({exc})") from exc
    if channel not in channels:
        raise DatasetError(f"{path}: missing EXR channel {channel!r}")
    return np.asarray(channels[channel].pixels, dtype=np.float64)


def box_downscale(img: np.ndarray, factor: int) -> np.ndarray:
    """Area-average by an integer factor (crops the remainder), the standard 3DGS downscale."""
    if factor == 1:
        return img
    h = img.shape[0] // factor * factor
    w = img.shape[1] // factor * factor
    x = img[:h, :w]
    shape = (h // factor, factor, w // factor, factor) + x.shape[2:]
    return x.reshape(shape).mean(axis=(1, 3))


def downscale_depth(depth: np.ndarray, factor: int) -> np.ndarray:
    """Mean of the valid (> 0) depths in each block; 0 where the block saw no surface."""
    if factor == 1:
        return depth
    valid = (depth > 0).astype(np.float64)
    num = box_downscale(depth * valid, factor)
    den = box_downscale(valid, factor)
    return np.where(den > 0.5, num / np.maximum(den, 1e-12), 0.0)


def _factor(width: int, max_width: int) -> int:
    return 1 if max_width <= 0 or width <= max_width else int(math.ceil(width / max_width))


def _check_image(arr: np.ndarray, path: Path, h: int, w: int) -> None:
    if arr.shape[0] != h or arr.shape[1] != w:
        raise DatasetError(f"{path}: image is {arr.shape[1]}x{arr.shape[0]}, transforms say {w}x{h}")


def _rgb01(arr: np.ndarray, path: Path) -> np.ndarray:
    """RGB in [0, 1]; grey is repeated, alpha dropped (straight RGB, docs/dataset-format.md)."""
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=-1)
    if arr.shape[-1] == 4:
        arr = arr[..., :3]
    if arr.shape[-1] != 3:
        raise DatasetError(f"{path}: expected an RGB image, got {arr.shape[-1]} channels")
    return image01(arr)


def _gray(arr: np.ndarray) -> np.ndarray:
    """Raw values as float64, colour averaged (thermal counts keep their own units)."""
    arr = arr.astype(np.float64)
    return arr if arr.ndim == 2 else arr[..., :3].mean(-1)


def _parse_transforms(path: Path, modality: str) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    data = load_json(path)
    for key in ("w", "h"):
        need_field(data, key, path, int)
    for key in ("fl_x", "fl_y", "cx", "cy"):
        need_field(data, key, path, (int, float))
    frames = need_field(data, "frames", path, list)
    if not frames:
        raise DatasetError(f"{path}: field 'frames' is empty")
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict):
            raise DatasetError(f"{path}: frames[{i}] is not an object")
        try:
            m = np.asarray(fr["transform_matrix"], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{path}: frames[{i}].transform_matrix is missing or not numeric") from exc
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise DatasetError(f"{path}: frames[{i}].transform_matrix must be a finite 4x4 matrix")
        if abs(np.linalg.det(m[:3, :3])) < 1e-8:
            raise DatasetError(f"{path}: frames[{i}].transform_matrix has a singular rotation")
    return data, frames


def _frames_from_transforms(path: Path, data: dict[str, Any], frames: list[dict[str, Any]],
                            factor: int, default_test_every: int) -> list[Frame]:
    w, h = int(data["w"]) // factor, int(data["h"]) // factor
    k = intrinsics(data["fl_x"] / factor, data["fl_y"] / factor, data["cx"] / factor, data["cy"] / factor)
    out = []
    for i, fr in enumerate(frames):
        stem = fr.get("file_stem") or Path(str(fr.get("file_path", f"{i:04d}"))).stem
        ts = fr.get("timestamp_s", None)
        if ts is not None and not isinstance(ts, (int, float)):
            raise DatasetError(f"{path}: frames[{i}].timestamp_s is not a number")
        split = fr.get("split")
        if split is None:
            split = "test" if default_test_every > 0 and i % default_test_every == default_test_every // 2 else "train"
        if split not in ("train", "test"):
            raise DatasetError(f"{path}: frames[{i}].split must be 'train' or 'test', got {split!r}")
        out.append(Frame(file_stem=str(stem), viewmat=c2w_gl_to_viewmat(np.asarray(fr["transform_matrix"])),
                         K=k.copy(), width=w, height=h,
                         timestamp_s=float(ts) if ts is not None else float(i),
                         time=float(fr.get("time", 0.0)), split=split))
    return out


def load_scene(path: Path, max_width: int = 0, thermal_scale: ThermalScaleSpec = LINEAR_SCALE) -> SceneData:
    """Load a generated dataset (has dataset.json), one of the official SmokeSeer layouts
    (transforms_train.json or sparse/0/images.bin), or a real capture (capture.json or
    COLMAP/transforms poses per modality)."""
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: not a directory")
    if (path / "dataset.json").exists():
        return _load_synthetic(path, max_width, thermal_scale)
    from smokeseer.official_layouts import detect_official_layout, load_official  # reads data.py's types

    layout = detect_official_layout(path)
    if layout is not None:
        return load_official(path, layout, max_width, thermal_scale)
    return _load_capture(path, max_width, thermal_scale)


def _load_synthetic(path: Path, max_width: int, thermal_scale: ThermalScaleSpec) -> SceneData:
    meta = load_json(path / "dataset.json")
    if meta.get("format") != "smokeseer-synth-dataset":
        raise DatasetError(f"{path / 'dataset.json'}: field 'format' must be 'smokeseer-synth-dataset'")
    passes = need_field(meta, "passes", path / "dataset.json", dict)
    smoke = meta.get("smoke", {}) if isinstance(meta.get("smoke", {}), dict) else {}
    rgb_passes = passes.get("rgb", [])
    if "smoky" not in rgb_passes:
        raise DatasetError(f"{path / 'dataset.json'}: field 'passes.rgb' must include 'smoky'")
    rgb = _load_synth_modality(path, "rgb", rgb_passes, max_width)
    thermal_passes = passes.get("thermal", [])
    thermal = (_load_synth_modality(path, "thermal", thermal_passes, max_width, thermal_scale)
               if "smoky" in thermal_passes else None)
    _set_times(rgb, thermal, meta.get("duration_s"))
    return SceneData(
        name=str(meta.get("scene", path.name)), path=path.resolve(), rgb=rgb, thermal=thermal,
        smoke_present=bool(smoke.get("present", True)), smoke_static=bool(smoke.get("static", False)),
        mask_threshold=float(smoke.get("mask_threshold", 0.02)), synthetic=True, meta=meta)


def _load_synth_modality(path: Path, modality: str, passes: list[str], max_width: int,
                         thermal_scale: ThermalScaleSpec = LINEAR_SCALE) -> ModalityData:
    tpath = path / f"transforms_{modality}.json"
    data, raw_frames = _parse_transforms(tpath, modality)
    factor = _factor(int(data["w"]), max_width)
    frames = _frames_from_transforms(tpath, data, raw_frames, factor, default_test_every=0)
    h0, w0 = int(data["h"]), int(data["w"])
    stems = [f.file_stem for f in frames]

    def stack(sub: str, reader) -> np.ndarray:
        imgs = []
        for stem in stems:
            p = path / modality / sub / f"{stem}{'.exr' if reader is not None else '.png'}"
            arr = reader(p) if reader is not None else read_png(p)
            _check_image(arr, p, h0, w0)
            imgs.append(arr)
        return np.stack(imgs)

    if modality == "rgb":
        images = np.stack([box_downscale(_rgb01(a, path / "rgb" / "smoky" / f"{s}.png"), factor)
                           for a, s in zip(stack("smoky", None), stems)])
        clean = (np.stack([box_downscale(_rgb01(a, path / "rgb" / "clean" / f"{s}.png"), factor)
                           for a, s in zip(stack("clean", None), stems)]) if "clean" in passes else None)
        scale = None
    else:
        images, scale = thermal_images(np.stack([_gray(a) for a in stack("smoky", None)]), factor, thermal_scale)
        clean = None
        if "clean" in passes:
            craw = np.stack([_gray(a) for a in stack("clean", None)])
            clean = np.stack([box_downscale(scale.apply(x), factor)[..., None] for x in craw])
    masks = depth = None
    if "smoke_alpha" in passes:
        masks = np.stack([box_downscale(_gray(a) / 255.0, factor) for a in stack("smoke_mask", None)])
    if "depth" in passes:
        depth = np.stack([downscale_depth(a, factor)
                          for a in stack("depth", lambda p: read_exr(p, "Z"))])
    _check_finite(images, path / modality / "smoky")
    return ModalityData(name=modality, frames=frames, images=images.astype(np.float32),
                        clean=None if clean is None else clean.astype(np.float32),
                        masks=None if masks is None else masks.astype(np.float32),
                        depth=None if depth is None else depth.astype(np.float32),
                        scale=scale)


def thermal_images(raw: np.ndarray, factor: int, spec: ThermalScaleSpec) -> tuple[np.ndarray, ThermalScale]:
    """Raw thermal frames [N, H, W] to training images [N, H/factor, W/factor, 1] through the
    dataset's curve, fitted on every full-resolution frame."""
    scale = spec.fit(raw)
    return np.stack([box_downscale(scale.apply(x), factor)[..., None] for x in raw]), scale


def _check_finite(arr: np.ndarray, where: Path) -> None:
    if not np.all(np.isfinite(arr)):
        raise DatasetError(f"{where}: images contain NaN or Inf")


def _set_times(rgb: ModalityData, thermal: ModalityData | None, duration: Any) -> None:
    """Normalised time from timestamps: t = (timestamp − first RGB timestamp) / duration."""
    frames = rgb.frames + (thermal.frames if thermal else [])
    t0 = min(f.timestamp_s for f in rgb.frames)
    if isinstance(duration, (int, float)) and duration > 0:
        span = float(duration)
    else:
        span = max(f.timestamp_s for f in frames) - t0
    span = span if span > 0 else 1.0
    for f in frames:
        f.time = float(np.clip((f.timestamp_s - t0) / span, 0.0, 1.0))


# ----------------------------------------------------------------------------- real captures

def _load_capture(path: Path, max_width: int, thermal_scale: ThermalScaleSpec) -> SceneData:
    meta = load_json(path / "capture.json") if (path / "capture.json").exists() else {}
    smoke = meta.get("smoke", {}) if isinstance(meta.get("smoke", {}), dict) else {}
    test_every = int(meta.get("test_every", 8))
    notes: list[str] = []
    rgb = _load_capture_modality(path, "rgb", max_width, test_every, notes, thermal_scale)
    if rgb is None:
        raise DatasetError(f"{path}: no RGB poses (need transforms_rgb.json or rgb/sparse/images.txt)")
    thermal = _load_capture_modality(path, "thermal", max_width, 0, notes, thermal_scale)
    _set_times(rgb, thermal, meta.get("duration_s"))
    points = None
    pts_file = path / "rgb" / "sparse" / "points3D.txt"
    if pts_file.exists():
        points = read_colmap_points(pts_file)
    return SceneData(
        name=str(meta.get("scene", path.name)), path=path.resolve(), rgb=rgb, thermal=thermal,
        smoke_present=bool(smoke.get("present", True)), smoke_static=bool(smoke.get("static", False)),
        mask_threshold=float(smoke.get("mask_threshold", 0.5)), synthetic=False,
        init_points=points, meta=meta, notes=notes)


def all_or_none(files: list[Path], kind: str, none_note: str, notes: list[str]) -> bool:
    """True when every per-frame file exists; False, noting ``none_note``, when none does. Some
    but not all is an error naming the first missing one: a silently partial term is worse."""
    present = [p.is_file() for p in files]
    if not any(present):
        notes.append(none_note)
        return False
    if not all(present):
        missing = files[present.index(False)]
        raise DatasetError(f"{missing}: missing {kind} ({sum(present)} of {len(files)} frames have one)")
    return True


def load_smoke_alpha(scene: SceneData, indices: list[int]) -> np.ndarray:
    """The generator's true RGB smoke alpha (``rgb/smoke_alpha``, channel A) of the given frames,
    area-averaged to the training resolution like the masks; DatasetError names a missing file."""
    rgb = scene.rgb
    height, width = rgb.images.shape[1:3]
    maps = []
    for i in indices:
        path = scene.path / "rgb" / "smoke_alpha" / f"{rgb.frames[i].file_stem}.exr"
        alpha = read_exr(path, "A")
        factor = alpha.shape[1] // width
        small = box_downscale(alpha, max(factor, 1))
        if small.shape[:2] != (height, width):
            raise DatasetError(f"{path}: {alpha.shape[1]}x{alpha.shape[0]} does not scale to the frames' {width}x{height}")
        maps.append(small)
    return np.stack(maps).astype(np.float32)


def load_masks(files: list[Path], factor: int, what: str, notes: list[str]) -> np.ndarray | None:
    """Binary smoke masks (> half scale = smoke) for every frame, or None with a note when the
    folder has none."""
    if not all_or_none(files, "mask", f"{what}: no smoke masks; the mask term is dropped unless Stage 1 "
                       "estimates masks", notes):
        return None
    return np.stack([box_downscale((_gray(image01(read_png(p))) > 0.5).astype(np.float64), factor)
                     for p in files]).astype(np.float32)


def _load_capture_modality(path: Path, modality: str, max_width: int, test_every: int, notes: list[str],
                           thermal_scale: ThermalScaleSpec) -> ModalityData | None:
    tpath = path / f"transforms_{modality}.json"
    colmap = path / modality / "sparse"
    if tpath.exists():
        data, raw = _parse_transforms(tpath, modality)
        factor = _factor(int(data["w"]), max_width)
        frames = _frames_from_transforms(tpath, data, raw, factor, test_every if modality == "rgb" else 0)
        if modality == "thermal":
            for f in frames:
                f.split = "train"
        files = [path / str(fr.get("file_path", f"{modality}/images/{f.file_stem}.png")) for fr, f in zip(raw, frames)]
        sizes = [(int(data["h"]), int(data["w"]))] * len(frames)
        from_poses = all("timestamp_s" in fr for fr in raw)
    elif (colmap / "images.txt").exists():
        frames, files, sizes, factor = _frames_from_colmap(path, modality, max_width, test_every)
        from_poses = False
    else:
        return None
    _apply_timestamps(path, modality, frames, from_poses, notes)
    imgs = []
    for fpath, (h, w) in zip(files, sizes):
        if not fpath.suffix:
            fpath = fpath.with_suffix(".png")
        arr = read_png(fpath)
        _check_image(arr, fpath, h, w)
        imgs.append(arr)
    masks = None
    if modality == "rgb":
        images = np.stack([box_downscale(_rgb01(a, p), factor) for a, p in zip(imgs, files)])
        scale = None
        masks = load_masks([path / "rgb" / "masks" / f"{f.file_stem}.png" for f in frames], factor,
                           f"{path / 'rgb' / 'masks'}", notes)
    else:
        images, scale = thermal_images(np.stack([_gray(a) for a in imgs]), factor, thermal_scale)
    _check_finite(images, path / modality)
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


def read_colmap_cameras(path: Path) -> dict[int, tuple[int, int, np.ndarray]]:
    """COLMAP cameras.txt → {camera_id: (width, height, K)}; only undistorted pinhole models."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    cams: dict[int, tuple[int, int, np.ndarray]] = {}
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split()
        try:
            cid, model, w, h = int(parts[0]), parts[1], int(parts[2]), int(parts[3])
            params = [float(p) for p in parts[4:]]
        except (IndexError, ValueError) as exc:
            raise DatasetError(f"{path}: line {line_no} is not 'ID MODEL W H PARAMS'") from exc
        if model == "PINHOLE" and len(params) == 4:
            k = intrinsics(*params)
        elif model == "SIMPLE_PINHOLE" and len(params) == 3:
            k = intrinsics(params[0], params[0], params[1], params[2])
        else:
            raise DatasetError(f"{path}: line {line_no}: camera model {model} is not supported; "
                               "undistort to PINHOLE first (colmap image_undistorter)")
        cams[cid] = (w, h, k)
    return cams


def _quat_to_rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def read_colmap_images(path: Path) -> list[tuple[str, int, np.ndarray]]:
    """COLMAP images.txt → [(name, camera_id, OpenCV world-to-camera 4×4)], sorted by name."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    out = []
    for i in range(0, len(lines), 2):
        line = lines[i]
        if not line.strip():
            continue
        parts = line.split()
        try:
            q = np.array([float(v) for v in parts[1:5]])
            t = np.array([float(v) for v in parts[5:8]])
            cid = int(parts[8])
            name = parts[9]
        except (IndexError, ValueError) as exc:
            raise DatasetError(f"{path}: entry {i // 2 + 1} is not 'ID QW QX QY QZ TX TY TZ CAM NAME'") from exc
        if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12 or not np.all(np.isfinite(t)):
            raise DatasetError(f"{path}: entry {i // 2 + 1} ({name}) has an invalid pose")
        v = np.eye(4)
        v[:3, :3] = _quat_to_rot(q)
        v[:3, 3] = t
        out.append((name, cid, v))
    if not out:
        raise DatasetError(f"{path}: no images listed")
    return sorted(out, key=lambda e: e[0])


def read_colmap_points(path: Path) -> np.ndarray:
    """COLMAP points3D.txt → N×3 positions (used to initialise Stage 2)."""
    pts = []
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        try:
            pts.append([float(v) for v in line.split()[1:4]])
        except ValueError as exc:
            raise DatasetError(f"{path}: line {line_no} has a non-numeric position") from exc
    return np.asarray(pts, dtype=np.float64).reshape(-1, 3)


def _frames_from_colmap(path: Path, modality: str, max_width: int,
                        test_every: int) -> tuple[list[Frame], list[Path], list[tuple[int, int]], int]:
    sparse = path / modality / "sparse"
    cams = read_colmap_cameras(sparse / "cameras.txt")
    images = read_colmap_images(sparse / "images.txt")
    widths = {w for w, _, _ in cams.values()}
    factor = _factor(max(widths), max_width)
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
        files.append(path / modality / "images" / name)
        sizes.append((h, w))
    return frames, files, sizes, factor
