"""NeRF-style ``transforms_MODALITY.json`` (our generated format and our capture layout) to frames.

Intrinsics and poses are checked by the format's own rules (``contracts.dataset_format``):
one pose check, a rigid camera-to-world matrix, for every layout.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from contracts.dataset_format import check_camera, check_pose, load_json, need_field
from contracts.errors import DatasetError
from scenes.cameras import c2w_gl_to_viewmat, intrinsics
from scenes.scene import Frame


def read_capture_transforms(path: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A capture's transforms file: intrinsics and at least one frame, each with a rigid pose
    (``file_path``, ``timestamp_s`` and ``split`` are optional there)."""
    data = load_json(path)
    check_camera(data, path)
    frames = need_field(data, "frames", path, list)
    if not frames:
        raise DatasetError(f"{path}: field 'frames' is empty")
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict):
            raise DatasetError(f"{path}: frames[{i}] is not an object")
        check_pose(fr.get("transform_matrix"), f"{path}: frames[{i}]")
    return data, frames


def frames_from_transforms(path: Path, data: dict[str, Any], frames: list[dict[str, Any]],
                           factor: int, default_test_every: int) -> list[Frame]:
    """Frames at the working resolution (``factor``). Without ``split`` fields every
    ``default_test_every``-th frame from half that is held out (0: none)."""
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
