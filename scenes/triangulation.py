"""Sparse points from images at known poses: COLMAP's features and verified matches
(``scenes.sfm.match_features``), joined into tracks across frames and triangulated at the given
cameras, with no pose estimated.

Why not SfM then a similarity onto the given poses: incremental mapping needs a well-posed
initial pair and registers nothing on some drawn flyovers (2 of 21 frames), while every pair of
frames with verified matches can be triangulated once the poses are known. A track is kept when
its point lies in front of every camera that sees it, reprojects within
``SfmSettings.filter_max_reproj_error`` (pixels of the upsampled frames, as SfM's filter) in each,
and is seen under at least ``filter_min_tri_angle`` between some two of them: the filters COLMAP's
mapper applies, so features on drifting smoke, which do not hold still between frames, fall out.
"""
from __future__ import annotations

import hashlib
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from contracts.atomic import atomic_path
from scenes.sfm import SfmSettings, digest, match_features, to_uint8


@dataclass
class Triangulated:
    """Points in the cameras' world and what it took."""

    points: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)


def one_camera(Ks: np.ndarray) -> bool:
    """Whether every frame has the same intrinsics: the matcher and the cache key assume one camera."""
    return all(np.allclose(k, Ks[0]) for k in Ks)


def triangulate_known(names: list[str], images: list[np.ndarray], viewmats: np.ndarray, Ks: np.ndarray,
                      settings: SfmSettings = SfmSettings(), cache: Path | None = None) -> Triangulated:
    """Points seen in ``images`` (one camera: every ``Ks`` equal) at the OpenCV world-to-camera
    ``viewmats``, cached in ``cache`` by the frames, poses, intrinsics and settings."""
    if not len(names) == len(images) == len(viewmats) == len(Ks):
        raise ValueError("triangulate_known: names, images, viewmats and Ks must have one entry per frame")
    if not one_camera(Ks):
        raise ValueError("triangulate_known: the frames must share one camera (intrinsics)")
    images = [to_uint8(a) for a in images]
    h = hashlib.sha256(digest(names, images, None, Ks[0], settings).encode())
    h.update(np.ascontiguousarray(np.asarray(viewmats, np.float64).round(9)).tobytes())
    cached = None if cache is None else Path(cache) / f"{h.hexdigest()}-known-poses.npz"
    if cached is not None and cached.is_file():
        with np.load(cached, allow_pickle=False) as z:
            return Triangulated(z["points"], {"cached": True, "tracks": int(z["tracks"])})
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tri-") as tmp:
        feats = match_features(Path(tmp), images, None, Ks[0], settings)
        observations, tracks = _tracks(feats.path, feats.files)
    scaled = np.array([[feats.up, 0, 0], [0, feats.up, 0], [0, 0, 1.0]]) @ Ks[0]
    projections = np.einsum("ij,njk->nik", scaled, np.asarray(viewmats, np.float64)[:, :3, :])
    points, kept = triangulate_tracks(observations, tracks, projections, settings.filter_max_reproj_error,
                                      settings.filter_min_tri_angle)
    stats = {"cached": False, "tracks": int(tracks.max() + 1) if len(tracks) else 0, "kept": int(kept.sum()),
             "verified_pairs": feats.pairs, "upsampled": feats.up,
             **{k: round(v, 3) for k, v in feats.timings.items()},
             "triangulate_s": round(time.perf_counter() - t0 - sum(feats.timings.values()), 3)}
    if cached is not None:
        cached.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(cached) as path:
            with open(path, "wb") as fh:
                np.savez(fh, points=points, tracks=np.array(stats["tracks"]))
    return Triangulated(points, stats)


def _tracks(db_path: Path, files: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Every keypoint that a verified match joins to another, as rows (frame, x, y) in the
    upsampled frame's pixels, and its track: the connected component of the matches."""
    import pycolmap

    db = pycolmap.Database.open(db_path)
    try:
        frame_of = {im.image_id: files.index(im.name) for im in db.read_all_images()}
        keypoints = {i: db.read_keypoints(i)[:, :2].astype(np.float64) for i in frame_of}
        pair_ids, geometries = db.read_two_view_geometries()
    finally:
        db.close()
    offset, start = {}, 0
    for i in sorted(frame_of):
        offset[i] = start
        start += len(keypoints[i])
    rows, cols = [], []
    for pair_id, geometry in zip(pair_ids, geometries):
        matches = np.asarray(geometry.inlier_matches)
        if len(matches) == 0:
            continue
        a, b = pycolmap.pair_id_to_image_pair(pair_id)
        rows.append(offset[a] + matches[:, 0])
        cols.append(offset[b] + matches[:, 1])
    if not rows:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r)), (r, c)), shape=(start, start))
    _, labels = connected_components(graph, directed=False)
    used = np.unique(np.concatenate([r, c]))
    frame = np.empty(start, dtype=np.int64)
    xy = np.empty((start, 2))
    for i in sorted(frame_of):
        frame[offset[i]:offset[i] + len(keypoints[i])] = frame_of[i]
        xy[offset[i]:offset[i] + len(keypoints[i])] = keypoints[i]
    _, track = np.unique(labels[used], return_inverse=True)
    return np.column_stack([frame[used], xy[used]]), track


def triangulate_tracks(observations: np.ndarray, tracks: np.ndarray, projections: np.ndarray,
                       max_error: float, min_angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """One point per track by the linear (DLT) solution over its observations (frame, x, y; COLMAP
    pixel coordinates, the top-left corner at 0) through the 3×4 ``projections``, kept when it
    lies in front of every camera, reprojects within ``max_error`` in each, and two of its rays
    meet at ``min_angle_deg`` or more. A track that sees one frame twice (a bad match) is left
    out. Returns the kept points and the keep flag per track."""
    n_tracks = int(tracks.max()) + 1 if len(tracks) else 0
    points = np.zeros((n_tracks, 3))
    kept = np.zeros(n_tracks, dtype=bool)
    order = np.argsort(tracks, kind="stable")
    bounds = np.searchsorted(tracks[order], np.arange(n_tracks + 1))
    centres = np.stack([-np.linalg.solve(p[:, :3], p[:, 3]) for p in projections])
    cos_min = np.cos(np.radians(min_angle_deg))
    for t in range(n_tracks):
        obs = observations[order[bounds[t]:bounds[t + 1]]]
        frames = obs[:, 0].astype(np.int64)
        if len(obs) < 2 or len(np.unique(frames)) < len(frames):
            continue
        p = projections[frames]
        rows = np.concatenate([obs[:, 1:2] * p[:, 2] - p[:, 0], obs[:, 2:3] * p[:, 2] - p[:, 1]])
        x = np.linalg.svd(rows)[2][-1]
        if abs(x[3]) < 1e-12:
            continue
        x = x[:3] / x[3]
        seen = p[:, :, :3] @ x + p[:, :, 3]
        if np.any(seen[:, 2] <= 0):
            continue
        error = np.linalg.norm(seen[:, :2] / seen[:, 2:3] - obs[:, 1:], axis=1)
        if np.any(error > max_error):
            continue
        rays = x - centres[frames]
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        if (rays @ rays.T).min() > cos_min:
            continue
        points[t], kept[t] = x, True
    return points[kept], kept
