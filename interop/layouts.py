"""Write a loaded scene in the official SmokeSeer layouts or as nerfstudio ``transforms.json``.

Every frame of the source is written. Names are ``rgb_DIGITS`` / ``thermal_DIGITS`` where the
digits are the frame's time in microseconds from the earliest frame, zero-padded: the official
COLMAP reader takes a name's digits as its frame number and sorts by name, so both modalities
share one clock and sorted order is time order. ``smokeseer_interop.json`` records what the
layouts cannot hold and everything that was substituted.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from interop.colmap_write import CameraRecord, ImageRecord, points3d_bin, write_model
from interop.resample import centred_intrinsics, needs_resample, warp_to_intrinsics
from scenes.cameras import backproject, scene_bounds, viewmat_to_c2w_gl
from scenes.official_depth import DEPTH_DIR, PARAMS_FILE, encode_inverse_depth, global_code, reciprocal_or_zero
from scenes.official_layouts import OFFICIAL_TEST_EVERY
from scenes.scene import Frame, ModalityData, SceneData

TARGETS = ("smokeseer-blender", "smokeseer-colmap", "nerfstudio")
SPLITS = ("official", "source")
TICK_S = 1e-6
DIGITS = 10
MAX_POINTS = 20_000


@dataclass
class OutFrame:
    """One frame ready to write: its name, pose, intrinsics after any resampling, and images."""

    name: str
    frame: Frame
    k: np.ndarray
    split: str
    image: np.ndarray
    clean: np.ndarray | None
    mask: np.ndarray | None
    depth: np.ndarray | None


@dataclass
class Conversion:
    target: str
    split: str
    points: bool
    notes: list[str] = field(default_factory=list)
    resampled: dict[str, float] = field(default_factory=dict)
    depth_sources: dict[str, str] = field(default_factory=dict)
    images_depth: str | None = None
    """What ``images_depth/`` holds ("ground-truth" or "prior"), None when it is not written."""


def _to8(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)


def _save(path: Path, arr: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(arr)).save(path, format="PNG")


def frame_names(scene: SceneData) -> tuple[dict[str, list[str]], float]:
    """Names with the shared microsecond clock, and its origin in source seconds."""
    mods = [m for m in (scene.rgb, scene.thermal) if m is not None]
    origin = min(f.timestamp_s for m in mods for f in m.frames)
    names: dict[str, list[str]] = {}
    for m in mods:
        ticks = [int(round((f.timestamp_s - origin) / TICK_S)) for f in m.frames]
        if len(set(ticks)) != len(ticks):
            raise ValueError(f"{scene.path}: two {m.name} frames share a timestamp; "
                             "frame names (and the official reader's frame numbers) would collide")
        if max(ticks) >= 10 ** DIGITS:
            raise ValueError(f"{scene.path}: {m.name} timestamps span more than {10 ** DIGITS * TICK_S:.0f} s")
        names[m.name] = [f"{m.name}_{t:0{DIGITS}d}" for t in ticks]
    return names, origin


def _prepare(mod: ModalityData, names: list[str], conv: Conversion, square: bool) -> list[OutFrame]:
    order = sorted(range(len(mod.frames)), key=lambda i: names[i])
    depths = source_depth(mod, conv)
    out = []
    for rank, i in enumerate(order):
        f = mod.frames[i]
        if conv.split == "official":
            split = "test" if rank % OFFICIAL_TEST_EVERY == 0 else "train"
        else:
            split = f.split
        image = mod.images[i] if mod.name == "rgb" else mod.images[i][..., 0]
        clean = None if mod.clean is None else (mod.clean[i] if mod.name == "rgb" else mod.clean[i][..., 0])
        mask = None if mod.masks is None else mod.masks[i]
        depth = None if depths is None else depths[i]
        k = f.K
        if needs_resample(f.K, f.width, f.height, square):
            k = centred_intrinsics(f.K, f.width, f.height, square)
            image, lost = warp_to_intrinsics(image, f.K, k)
            clean = None if clean is None else warp_to_intrinsics(clean, f.K, k)[0]
            mask = None if mask is None else warp_to_intrinsics(mask, f.K, k, nearest=True)[0]
            depth = None if depth is None else warp_to_intrinsics(depth, f.K, k, nearest=True)[0]
            conv.resampled[names[i]] = lost
        out.append(OutFrame(names[i], f, k, split, image, clean, mask, depth))
    if conv.resampled:
        worst = max(conv.resampled.values())
        conv.notes.append(f"{mod.name}: {len(conv.resampled)} frames resampled to a centred principal point"
                          f"{' and square pixels' if square else ''}; up to {100 * worst:.1f} % of a frame "
                          "fell outside the source and is black")
    return out


def source_depth(mod: ModalityData, conv: Conversion) -> np.ndarray | None:
    """Planar depth per frame for ``images_depth/``: the source's ground truth, else the inverse
    depth prior it carries (an official layout read back), said in the notes."""
    if mod.depth is not None:
        conv.depth_sources[mod.name] = "ground-truth"
        return mod.depth
    if mod.inverse_depth is not None:
        conv.depth_sources[mod.name] = "prior"
        return reciprocal_or_zero(mod.inverse_depth)
    return None


def prepare(scene: SceneData, conv: Conversion) -> tuple[dict[str, list[OutFrame]], float]:
    names, origin = frame_names(scene)
    square = conv.target == "smokeseer-blender"
    frames = {"rgb": _prepare(scene.rgb, names["rgb"], conv, square)}
    if scene.thermal is not None:
        frames["thermal"] = _prepare(scene.thermal, names["thermal"], conv, square)
    else:
        conv.notes.append("source has no thermal frames; only RGB is written")
    if scene.rgb.clean is None:
        conv.notes.append("source has no smoke-free RGB; no NAME_gt images are written")
    if scene.rgb.masks is None:
        conv.notes.append("source has no smoke masks; no masks are written")
    return frames, origin


def sidecar(scene: SceneData, conv: Conversion, origin: float) -> dict[str, Any]:
    """What the official layouts cannot hold, for our loader, plus every substitution made."""
    rgb_ts = [f.timestamp_s for f in scene.rgb.frames]
    duration = scene.meta.get("duration_s")
    if not isinstance(duration, (int, float)) or duration <= 0:
        everything = rgb_ts + ([f.timestamp_s for f in scene.thermal.frames] if scene.thermal else [])
        duration = max(everything) - min(rgb_ts) or 1.0
    return {
        "format": "smokeseer-interop", "format_version": 1, "layout": conv.target, "scene": scene.name,
        "source": str(scene.path), "tick_s": TICK_S, "time_origin_s": origin, "duration_s": float(duration),
        "split": conv.split, "smoke": {"present": scene.smoke_present, "static": scene.smoke_static},
        "thermal_counts_range": list(scene.thermal.scale.raw_range) if scene.thermal and scene.thermal.scale
        else None,
        "images_depth": conv.images_depth,
        "notes": scene.notes + conv.notes,
    }


def _points(scene: SceneData, conv: Conversion) -> tuple[np.ndarray, np.ndarray]:
    """Initial points: the source's smoke-free depth back-projected from RGB training frames, else
    uniform points in the cameras' view box (said in the notes either way)."""
    rng = np.random.default_rng(0)
    mod = scene.rgb
    if mod.depth is not None:
        xyz, rgb = [], []
        colour = mod.clean if mod.clean is not None else mod.images
        for i, f in enumerate(mod.frames):
            if f.split != "train":
                continue
            v, u = np.nonzero(mod.depth[i] > 0)
            xyz.append(backproject(mod.depth[i][v, u], np.stack([u, v], 1), f.viewmat, f.K))
            rgb.append(colour[i][v, u])
        pts, cols = np.concatenate(xyz), np.concatenate(rgb)
        keep = rng.choice(len(pts), size=min(MAX_POINTS, len(pts)), replace=False)
        conv.notes.append(f"points3D: {len(keep)} points back-projected from the source's smoke-free "
                          "ground-truth depth (a real capture would use SfM points)")
        return pts[keep], _to8(cols[keep])
    train = [f for f in mod.frames if f.split == "train"] or mod.frames
    b = scene_bounds(np.stack([f.viewmat for f in train]), np.stack([f.K for f in train]),
                     np.array([f.width for f in train]))
    n = 10_000
    conv.notes.append(f"points3D: source has no depth; {n} uniform random points in the cameras' view box")
    return b.center + rng.uniform(-1, 1, size=(n, 3)) * b.half_size, np.full((n, 3), 128, dtype=np.uint8)


# ----------------------------------------------------------------------------- writers

def write_blender(scene: SceneData, frames: dict[str, list[OutFrame]], out: Path, conv: Conversion) -> None:
    """transforms_{train,test,thermaltrain,thermaltest}.json, RGBA PNGs, NAME_gt.png beside each RGB
    frame, and RGB smoke masks in ``rgb_mask/`` (the COLMAP layout's ``_mask`` convention)."""
    for modality, files in (("rgb", ("transforms_train.json", "transforms_test.json")),
                            ("thermal", ("transforms_thermaltrain.json", "transforms_thermaltest.json"))):
        items = frames.get(modality)
        if items is None:
            continue
        k, w = items[0].k, items[0].frame.width
        if any(abs(it.k[0, 0] - k[0, 0]) > 1e-9 or it.frame.width != w for it in items):
            raise ValueError(f"{scene.path}: {modality} frames differ in focal length or size; the Blender layout "
                             "holds one camera_angle_x per file")
        fovx = 2.0 * math.atan(0.5 * w / k[0, 0])
        by_split: dict[str, list[dict[str, Any]]] = {"train": [], "test": []}
        for it in items:
            rel = f"{modality}/{it.name}"
            if it.image.ndim == 2:
                rgb8 = np.repeat(_to8(it.image)[..., None], 3, axis=-1)
            else:
                rgb8 = _to8(it.image)
            _save(out / f"{rel}.png", np.dstack([rgb8, np.full(rgb8.shape[:2], 255, np.uint8)]))
            if modality == "rgb" and it.clean is not None:
                _save(out / f"{rel}_gt.png", np.dstack([_to8(it.clean), np.full(rgb8.shape[:2], 255, np.uint8)]))
            if modality == "rgb" and it.mask is not None:
                _save(out / "rgb_mask" / f"{it.name}.png", np.where(it.mask > 0.5, 255, 0).astype(np.uint8))
            by_split[it.split].append({"file_path": f"./{rel}", "frame": float(it.frame.time),
                                       "transform_matrix": viewmat_to_c2w_gl(it.frame.viewmat).tolist()})
        for split, name in zip(("train", "test"), files):
            (out / name).write_text(json.dumps({"camera_angle_x": fovx, "frames": by_split[split]}, indent=1))
    if conv.points:
        xyz, rgb = _points(scene, conv)
        (out / "sparse_colmap").mkdir(parents=True, exist_ok=True)
        (out / "sparse_colmap" / "points3D.bin").write_bytes(points3d_bin(xyz, rgb))


def write_colmap(scene: SceneData, frames: dict[str, list[OutFrame]], out: Path, conv: Conversion) -> None:
    """images/ (3-channel 8-bit, NAME_gt beside RGB), images_mask/ (RGB: smoke mask; thermal: an
    all-ones multiplicative mask), sparse/0/*.bin: one model, one world frame, camera 1 RGB and
    camera 2 thermal."""
    cameras, images = [], []
    image_id = 1
    for cam_id, modality in enumerate(("rgb", "thermal"), start=1):
        items = frames.get(modality)
        if items is None:
            continue
        ks = {tuple(np.round(it.k.ravel(), 9)) for it in items}
        if len(ks) != 1:
            raise ValueError(f"{scene.path}: {modality} frames have {len(ks)} different intrinsics; "
                             "the conversion writes one camera per modality")
        k, f0 = items[0].k, items[0].frame
        cameras.append(CameraRecord(cam_id, "PINHOLE", f0.width, f0.height, (k[0, 0], k[1, 1], k[0, 2], k[1, 2])))
        for it in items:
            img8 = _to8(it.image) if it.image.ndim == 3 else np.repeat(_to8(it.image)[..., None], 3, axis=-1)
            _save(out / "images" / f"{it.name}.png", img8)
            if modality == "rgb" and it.clean is not None:
                _save(out / "images" / f"{it.name}_gt.png", _to8(it.clean))
            if modality == "rgb" and it.mask is not None:
                _save(out / "images_mask" / f"{it.name}.png", np.where(it.mask > 0.5, 255, 0).astype(np.uint8))
            elif modality == "thermal":
                _save(out / "images_mask" / f"{it.name}.png", np.full(img8.shape[:2], 255, np.uint8))
            images.append(ImageRecord(image_id, it.frame.viewmat, cam_id, f"{it.name}.png"))
            image_id += 1
    xyz, rgb = _points(scene, conv)
    write_model(out / "sparse" / "0", cameras, images, xyz, rgb)
    write_images_depth(frames, out, conv)


def write_images_depth(frames: dict[str, list[OutFrame]], out: Path, conv: Conversion) -> None:
    """``images_depth/NAME.png`` (16-bit inverse depth) for every image and
    ``sparse/0/depth_params.json``, by the official reader's rules (``scenes.official_depth``).
    The official reader, given ``--depths``, opens a map for every image, RGB and thermal, so
    the maps are written only when every frame has depth."""
    lacking = [m for m in frames if conv.depth_sources.get(m) is None]
    if lacking:
        conv.notes.append(f"images_depth: not written, the source has no depth for its {' and '.join(lacking)} "
                          "frames (the official reader needs a map for every image)")
        return
    items = [it for m in frames.values() for it in m]
    code = global_code([it.depth for it in items if it.depth is not None])
    params = {}
    for it in items:
        assert it.depth is not None
        _save(out / DEPTH_DIR / f"{it.name}.png", encode_inverse_depth(it.depth, code))
        params[it.name] = code.to_dict()
    (out / "sparse" / "0" / PARAMS_FILE).write_text(json.dumps(params, indent=1))
    sources = set(conv.depth_sources.values())
    conv.images_depth = "ground-truth" if sources == {"ground-truth"} else "prior"
    what = ("the source's smoke-free ground-truth depth (a real capture would use a monocular network's "
            "maps scaled to its SfM points)" if conv.images_depth == "ground-truth" else
            "the source's images_depth prior, not ground truth")
    conv.notes.append(f"images_depth: 16-bit inverse planar depth of all {len(items)} frames from {what}; "
                      f"depth_params.json gives every image scale {code.scale:.6g}, offset 0")


def write_nerfstudio(scene: SceneData, frames: dict[str, list[OutFrame]], out: Path, conv: Conversion) -> None:
    """One nerfstudio ``transforms.json`` per modality (OpenGL c2w, pixel intrinsics), with the
    split as ``train_filenames``/``test_filenames``; smoke-free truth in ``images_gt/`` and smoke
    masks (1 = smoke, not nerfstudio's ignore mask) in ``smoke_masks/``."""
    for modality, items in frames.items():
        root = out / modality
        k, f0 = items[0].k, items[0].frame
        doc: dict[str, Any] = {"camera_model": "OPENCV", "w": f0.width, "h": f0.height, "fl_x": k[0, 0],
                               "fl_y": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "k1": 0.0, "k2": 0.0,
                               "p1": 0.0, "p2": 0.0, "frames": [], "train_filenames": [], "test_filenames": []}
        for it in items:
            rel = f"images/{it.name}.png"
            img8 = _to8(it.image) if it.image.ndim == 3 else np.repeat(_to8(it.image)[..., None], 3, axis=-1)
            _save(root / rel, img8)
            if it.clean is not None and modality == "rgb":
                _save(root / "images_gt" / f"{it.name}.png", _to8(it.clean))
            if it.mask is not None and modality == "rgb":
                _save(root / "smoke_masks" / f"{it.name}.png", np.where(it.mask > 0.5, 255, 0).astype(np.uint8))
            kk = it.k
            doc["frames"].append({"file_path": rel, "transform_matrix": viewmat_to_c2w_gl(it.frame.viewmat).tolist(),
                                  "fl_x": kk[0, 0], "fl_y": kk[1, 1], "cx": kk[0, 2], "cy": kk[1, 2],
                                  "time": it.frame.time, "timestamp_s": it.frame.timestamp_s})
            doc[f"{it.split}_filenames"].append(rel)
        (root / "transforms.json").write_text(json.dumps(doc, indent=1))


WRITERS = {"smokeseer-blender": write_blender, "smokeseer-colmap": write_colmap, "nerfstudio": write_nerfstudio}

