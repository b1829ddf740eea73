"""Decoded image files to the arrays the trainer sees: channels, working size, masks, thermal.

Files are read by ``contracts.imageio`` (the one reader); what differs between layouts is
only the rule each applies here: straight RGB with alpha dropped (our formats) or RGBA
composited on black (the official Blender reader).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from contracts.errors import DatasetError
from contracts.imageio import image01, read_png
from scenes.thermal_scale import ThermalScale, ThermalScaleSpec


def working_factor(width: int, max_width: int) -> int:
    """The integer downscale that brings ``width`` to at most ``max_width`` (0: full size)."""
    return 1 if max_width <= 0 or width <= max_width else int(math.ceil(width / max_width))


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


def check_size(arr: np.ndarray, path: Path, h: int, w: int, source: str) -> None:
    """The image is ``w``×``h`` as ``source`` (the poses' file) says."""
    if arr.shape[0] != h or arr.shape[1] != w:
        raise DatasetError(f"{path}: image is {arr.shape[1]}x{arr.shape[0]}, {source} says {w}x{h}")


def rgb01(arr: np.ndarray, path: Path) -> np.ndarray:
    """RGB in [0, 1]; grey is repeated, alpha dropped (straight RGB, docs/dataset-format.md)."""
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=-1)
    if arr.shape[-1] == 4:
        arr = arr[..., :3]
    if arr.shape[-1] != 3:
        raise DatasetError(f"{path}: expected an RGB image, got {arr.shape[-1]} channels")
    return image01(arr)


def rgba_on_black(arr: np.ndarray) -> np.ndarray:
    """The official Blender reader's rule: the image as RGBA, composited over a black background."""
    x = image01(arr)
    if x.ndim == 2:
        return np.repeat(x[..., None], 3, axis=-1)
    if x.shape[-1] == 2:
        return np.repeat(x[..., :1] * x[..., 1:2], 3, axis=-1)
    if x.shape[-1] == 4:
        return x[..., :3] * x[..., 3:4]
    return x[..., :3]


def gray(arr: np.ndarray) -> np.ndarray:
    """Raw values as float64, colour averaged (thermal counts keep their own units)."""
    arr = arr.astype(np.float64)
    return arr if arr.ndim == 2 else arr[..., :3].mean(-1)


def thermal_images(raw: np.ndarray, factor: int, spec: ThermalScaleSpec) -> tuple[np.ndarray, ThermalScale]:
    """Raw thermal frames [N, H, W] to training images [N, H/factor, W/factor, 1] through the
    dataset's curve, fitted on every full-resolution frame."""
    scale = spec.fit(raw)
    return np.stack([box_downscale(scale.apply(x), factor)[..., None] for x in raw]), scale


def check_finite(arr: np.ndarray, where: Path) -> None:
    if not np.all(np.isfinite(arr)):
        raise DatasetError(f"{where}: images contain NaN or Inf")


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


def load_masks(files: list[Path], factor: int, what: str, notes: list[str]) -> np.ndarray | None:
    """Binary smoke masks (> half scale = smoke) for every frame, or None with a note when the
    folder has none."""
    if not all_or_none(files, "mask", f"{what}: no smoke masks; the mask term is dropped unless Stage 1 "
                       "estimates masks", notes):
        return None
    return np.stack([box_downscale((gray(image01(read_png(p))) > 0.5).astype(np.float64), factor)
                     for p in files]).astype(np.float32)
