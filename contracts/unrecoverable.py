"""The unrecoverable region of a dataset's test views: pixels whose surface no training view sees
clear of smoke (docs/dataset-format.md, "Statistics").

A method that reads RGB alone learns a surface point's colour only from the training views that
see it through thin smoke; a point that every training view sees behind dense smoke, or does not
see at all (out of frame, occluded), is out of its reach. One definition serves the generator's
statistics (`unrecoverable_share` in dataset.json) and the evaluation's region split
(eval/regions.py), both computed from the dataset's ground truth: planar depth, smoke opacity and
camera poses.

Each test pixel's surface point is the pixel centre back-projected to its depth (a pixel with no
surface, depth 0, is the direction at infinity through its centre). It is projected into every
training view; it counts as seen clear there when one of the four pixels around its projection
shows a surface at or beyond it (depth at least the point's planar depth over 1 +
``DEPTH_TOLERANCE``: nothing nearer hides it) with smoke alpha below ``CLEAR_ALPHA``. A direction
at infinity needs a pixel with no surface instead.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.dataset_format import PASS_FILES, file_path, transforms_name
from contracts.imageio import read_exr_channel

CLEAR_ALPHA = 0.1
"""A training view sees a point clear when the smoke in front of it is thinner than this."""
DEPTH_TOLERANCE = 0.02
"""Relative slack of the occlusion test: the depth pass is sampled at pixel centres, so a point on
a slanted surface can lie a little beyond the depth of the pixel it projects into."""


@dataclass(frozen=True)
class DepthView:
    """One RGB frame's camera (OpenGL c2w, pinhole intrinsics in pixels, pixel centres at +0.5), its
    planar depth (0 where no surface is hit) and its smoke opacity, both H×W."""

    c2w: np.ndarray
    fl_x: float
    fl_y: float
    cx: float
    cy: float
    depth: np.ndarray
    alpha: np.ndarray


def _rays(view: DepthView) -> np.ndarray:
    """Camera-frame direction of every pixel centre, scaled to planar depth 1 (z = -1), H×W×3."""
    h, w = view.depth.shape
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    return np.stack([(u - view.cx) / view.fl_x, -(v - view.cy) / view.fl_y, -np.ones_like(u)], axis=-1)


def _seen_clear(points: np.ndarray, at_infinity: np.ndarray, view: DepthView) -> np.ndarray:
    """Which world points (N×3; rows of ``at_infinity`` are directions) ``view`` sees clear."""
    rot, centre = view.c2w[:3, :3], view.c2w[:3, 3]
    local = np.where(at_infinity[:, None], points, points - centre) @ rot  # rot.T @ p per row
    z = -local[:, 2]
    in_front = z > 1e-9
    safe = np.where(in_front, z, 1.0)
    u = view.fl_x * local[:, 0] / safe + view.cx - 0.5  # continuous pixel index of the centre grid
    v = -view.fl_y * local[:, 1] / safe + view.cy - 0.5
    h, w = view.depth.shape
    seen = np.zeros(len(points), dtype=bool)
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    for du in (0, 1):
        for dv in (0, 1):
            ui, vi = u0 + du, v0 + dv
            inside = in_front & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
            uc, vc = np.clip(ui, 0, w - 1), np.clip(vi, 0, h - 1)
            depth, alpha = view.depth[vc, uc], view.alpha[vc, uc]
            visible = np.where(at_infinity, depth <= 0, (depth > 0) & (z <= depth * (1 + DEPTH_TOLERANCE)))
            seen |= inside & visible & (alpha < CLEAR_ALPHA)
    return seen


def unrecoverable_mask(test: DepthView, training: list[DepthView]) -> np.ndarray:
    """H×W: True where no view of ``training`` sees the test pixel's surface point clear of smoke."""
    rays = _rays(test).reshape(-1, 3)
    depth = test.depth.reshape(-1).astype(np.float64)
    at_infinity = depth <= 0
    rot, centre = test.c2w[:3, :3], test.c2w[:3, 3]
    points = np.where(at_infinity[:, None], rays @ rot.T, (rays * depth[:, None]) @ rot.T + centre)
    seen = np.zeros(len(points), dtype=bool)
    for view in training:
        seen |= _seen_clear(points, at_infinity, view)
    return ~seen.reshape(test.depth.shape)


def dataset_unrecoverable(root: Path) -> dict[str, np.ndarray]:
    """The unrecoverable mask of every RGB test view of the dataset at ``root``, by file stem, at
    the dataset's resolution. It needs the RGB depth and smoke opacity passes; a missing file is
    a DatasetError naming it."""
    transforms = json.loads((Path(root) / transforms_name("rgb")).read_text())
    depth_file, alpha_file = PASS_FILES[("rgb", "depth")][0], PASS_FILES[("rgb", "smoke_alpha")][0]

    def view(frame: dict) -> DepthView:
        stem = frame["file_stem"]
        return DepthView(np.asarray(frame["transform_matrix"], dtype=np.float64), float(transforms["fl_x"]),
                         float(transforms["fl_y"]), float(transforms["cx"]), float(transforms["cy"]),
                         read_exr_channel(file_path(root, depth_file, stem), "Z").astype(np.float64),
                         read_exr_channel(file_path(root, alpha_file, stem), "A").astype(np.float64))

    training = [view(f) for f in transforms["frames"] if f["split"] == "train"]
    return {f["file_stem"]: unrecoverable_mask(view(f), training)
            for f in transforms["frames"] if f["split"] == "test"}
