"""Depth maps of the official SmokeSeer COLMAP layout, both directions.

The official reader (cmu-ci-lab/SmokeSeer, ``scene/dataset_readers.py`` and
``utils/camera_utils.py``; the convention of 3DGS's depth regularisation) takes, for every
image of ``images/`` (RGB and thermal alike), ``images_depth/NAME.png``: inverse depth as a
PNG whose raw value divided by 2^16 is a relative inverse depth. ``sparse/0/depth_params.json``
maps NAME (the image name without its extension) to ``{"scale", "offset"}`` so that
``raw / 2^16 · scale + offset`` is inverse depth in the COLMAP model's units. The reader takes
``med_scale``, the median of the positive scales, and distrusts (masks out) an image whose scale
lies outside [0.2, 5] × med_scale; an image without an entry is used unscaled, and a scale
≤ 0 is not applied. Negative values are clipped to 0.

Writing, one global scale serves every image: the maps share one unit, every image passes the
reliability test, and 0 keeps meaning "no surface" (offset 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.dataset_format import load_json
from contracts.errors import DatasetError
from contracts.imageio import read_png
from scenes.images import all_or_none, downscale_depth

DEPTH_DIR = "images_depth"
PARAMS_FILE = "depth_params.json"
RAW_DIVISOR = 2.0 ** 16
"""The official reader divides the stored value by 2^16 whatever the PNG's bit depth."""
RELIABLE = (0.2, 5.0)
"""An image's scale must lie within these multiples of the median scale to be trusted."""
_MAX_CODE = 65535


@dataclass
class InverseDepthCode:
    """How stored 16-bit values map to inverse depth: ``value / 2^16 · scale + offset``."""

    scale: float
    offset: float = 0.0

    def to_dict(self) -> dict[str, float]:
        return {"scale": self.scale, "offset": self.offset}


def reciprocal_or_zero(x: np.ndarray) -> np.ndarray:
    """Depth ↔ inverse depth, keeping 0 for "no surface" both ways."""
    return np.where(x > 0, 1.0 / np.where(x > 0, x, 1.0), 0.0)


def global_code(depths: list[np.ndarray]) -> InverseDepthCode:
    """One code for all maps: the largest inverse depth (nearest surface) gets the top value.
    Quantisation then errs by at most half a step, a relative depth error of
    d / (2 · 65535 · d_min) for a surface at depth d when the nearest one is at d_min."""
    nearest = min(float(d[d > 0].min()) for d in depths if np.any(d > 0))
    return InverseDepthCode(scale=(1.0 / nearest) * RAW_DIVISOR / _MAX_CODE)


def encode_inverse_depth(depth: np.ndarray, code: InverseDepthCode) -> np.ndarray:
    """Planar depth (0 = no surface) → uint16 inverse-depth image under ``code``."""
    inv = reciprocal_or_zero(depth)
    values = np.round((inv - code.offset) / code.scale * RAW_DIVISOR)
    return np.clip(np.where(depth > 0, values, 0), 0, _MAX_CODE).astype(np.uint16)


@dataclass
class DepthFiles:
    """Inverse depth per frame in the model's units (0 = no prior there), at the working size."""

    inverse: np.ndarray
    unreliable: list[str]


def _read_params(path: Path) -> dict[str, tuple[float, float]]:
    data = load_json(path)
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected an object mapping image names to {{scale, offset}}")
    out = {}
    for name, entry in data.items():
        if not isinstance(entry, dict):
            raise DatasetError(f"{path}: {name!r}: expected an object with 'scale' and 'offset'")
        for key in ("scale", "offset"):
            value = entry.get(key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise DatasetError(f"{path}: {name!r}.{key}: missing or not a finite number")
        out[name] = (float(entry["scale"]), float(entry["offset"]))
    return out


def read_depth_files(root: Path, stems: list[str], size: tuple[int, int], factor: int,
                     what: str, notes: list[str]) -> DepthFiles | None:
    """``images_depth/STEM.png`` for every stem (one modality), decoded by the official rules, or
    None with a note when the layout has no maps for these frames. Some but not all present,
    or ``images_depth/`` without ``depth_params.json``, is an error."""
    folder = root / DEPTH_DIR
    if not folder.is_dir():
        return None
    files = [folder / f"{s}.png" for s in stems]
    if not all_or_none(files, f"{what} depth map", f"{folder}: no depth maps for the {what} frames", notes):
        return None
    params_path = root / "sparse" / "0" / PARAMS_FILE
    if not params_path.is_file():
        raise DatasetError(f"{params_path}: missing file ({folder} needs its per-image scale and offset)")
    params = _read_params(params_path)
    positive = [s for s, _ in params.values() if s > 0]
    med = float(np.median(positive)) if positive else 0.0
    maps, unreliable, unscaled = [], [], []
    for stem, p in zip(stems, files):
        raw = read_png(p)
        raw = raw[..., 0] if raw.ndim == 3 else raw
        if raw.shape != size:
            raise DatasetError(f"{p}: depth map is {raw.shape[1]}x{raw.shape[0]}, the image is {size[1]}x{size[0]}")
        inv = raw.astype(np.float64) / RAW_DIVISOR
        entry = params.get(stem)
        if entry is None:
            unscaled.append(stem)
        else:
            scale, offset = entry
            if scale < RELIABLE[0] * med or scale > RELIABLE[1] * med:
                unreliable.append(stem)
                inv = np.zeros_like(inv)
            elif scale > 0:
                inv = inv * scale + offset
        maps.append(downscale_depth(np.maximum(inv, 0.0), factor))
    if unscaled:
        notes.append(f"{params_path}: no entry for {len(unscaled)} {what} frames (first {unscaled[0]}); their "
                     "depth maps are used unscaled, as the official reader does")
    if unreliable:
        notes.append(f"{params_path}: {len(unreliable)} {what} frames have a scale outside "
                     f"[{RELIABLE[0]}, {RELIABLE[1]}] x the median {med:.6g}; their depth maps are not used, as the "
                     "official reader does")
    return DepthFiles(np.stack(maps).astype(np.float32), unreliable)
