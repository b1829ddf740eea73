"""Camera conventions and scene bounds.

The datasets store camera-to-world matrices in OpenGL/Blender axes; the rasterizer wants
OpenCV world-to-camera matrices. Keeping every conversion here gives one place to get it right.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

GL_TO_CV_AXES = np.array([1.0, -1.0, -1.0])
"""Blender/OpenGL camera axes (+Y up, −Z forward) to OpenCV's (+Y down, +Z forward), per axis."""
_GL_TO_CV = np.diag([*GL_TO_CV_AXES, 1.0])


def c2w_gl_to_viewmat(c2w: np.ndarray) -> np.ndarray:
    """OpenGL camera-to-world → OpenCV world-to-camera (flip camera Y and Z, then invert)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    return np.linalg.inv(c2w @ _GL_TO_CV)


def viewmat_to_c2w_gl(viewmat: np.ndarray) -> np.ndarray:
    """OpenCV world-to-camera → OpenGL camera-to-world (the inverse of ``c2w_gl_to_viewmat``)."""
    return np.linalg.inv(viewmat) @ _GL_TO_CV


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), COLMAP's order, to a 3×3 rotation (``q`` is normalised first)."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def camera_center(viewmat: np.ndarray) -> np.ndarray:
    return -viewmat[:3, :3].T @ viewmat[:3, 3]


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


@dataclass
class SceneBounds:
    """Where Gaussians are initialised: a centre, a half-size, and the 3DGS scene extent."""

    center: np.ndarray
    half_size: float
    extent: float


POINTS_QUANTILE = 75.0
"""With points, the half-size is ``POINTS_GROWTH`` × this percentile of their largest per-axis
distance from their median: a flyover's points include a tenth or more far away (the ground to
the horizon, poorly triangulated far features), which a box over all of them would take in ..."""
POINTS_GROWTH = 1.5
"""... and the growth brings back the rest of the scene around its densest three quarters."""


def scene_bounds(viewmats: np.ndarray, Ks: np.ndarray, widths: np.ndarray,
                 points: np.ndarray | None = None) -> SceneBounds:
    """Estimate the observed region from the cameras, or from points seen in the images (no GT
    geometry is used).

    Without ``points`` the centre is the least-squares point nearest all optical axes (cameras of
    a capture look at the scene) and the half-size the image half-width at the mean camera
    distance, so the box covers what the cameras see; the axes of a flyover need not meet near
    the scene, so that box can miss it. With ``points`` the centre is their per-axis median and
    the half-size as ``POINTS_QUANTILE`` says. The extent is 1.1 × the larger of the half-size
    and 3DGS's (the largest camera distance from the mean camera centre), floored so a static
    camera still gets a usable scale.
    """
    centres = np.stack([camera_center(v) for v in viewmats])
    spread = np.linalg.norm(centres - centres.mean(0), axis=1).max()
    if points is not None and len(points) > 0:
        center = np.median(points, axis=0)
        reach = np.percentile(np.abs(points - center).max(axis=1), POINTS_QUANTILE)
        half_size = float(max(POINTS_GROWTH * reach, 1e-3))
        return SceneBounds(center=center, half_size=half_size, extent=float(1.1 * max(spread, half_size)))
    dirs = np.stack([v[2, :3] for v in viewmats])
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(centres, dirs):
        p = np.eye(3) - np.outer(d, d)
        a += p
        b += p @ c
    if np.linalg.cond(a) < 1e8:
        center = np.linalg.solve(a, b)
        dist = np.linalg.norm(centres - center, axis=1).mean()
    else:
        dist = 1.0
        center = centres.mean(0) + dirs.mean(0) * dist
    half_fov = np.mean([math.atan(0.5 * w / k[0, 0]) for k, w in zip(Ks, widths)])
    half_size = float(max(dist * math.tan(half_fov), 1e-3))
    extent = float(1.1 * max(spread, half_size))
    return SceneBounds(center=center, half_size=half_size, extent=extent)


def project(points: np.ndarray, viewmat: np.ndarray, K: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixel coordinates (u, v), camera depth z and whether each point is in front of the camera
    (u and v are finite but meaningless for points that are not)."""
    pc = points @ viewmat[:3, :3].T + viewmat[:3, 3]
    z = pc[:, 2]
    ahead = z > 1e-6
    safe = np.where(ahead, z, 1.0)
    return K[0, 0] * pc[:, 0] / safe + K[0, 2], K[1, 1] * pc[:, 1] / safe + K[1, 2], z, ahead


def pixels_of(points: np.ndarray, viewmat: np.ndarray, K: np.ndarray, width: int, height: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which points land inside the image in front of the camera, the column and row of the pixel
    each of those lands in, and every point's camera depth z."""
    u, v, z, ahead = project(points, viewmat, K)
    u, v = np.floor(u), np.floor(v)
    inside = ahead & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    return inside, u[inside].astype(int), v[inside].astype(int), z


def backproject(depth: np.ndarray, pixels_uv: np.ndarray, viewmat: np.ndarray, K: np.ndarray) -> np.ndarray:
    """World points seen at pixel centres ``pixels_uv`` (n, 2, integer) with planar ``depth`` (n,):
    the inverse of ``project``."""
    homog = np.stack([pixels_uv[:, 0] + 0.5, pixels_uv[:, 1] + 0.5, np.ones(len(depth))])
    cam = np.linalg.inv(K) @ homog * depth
    return (np.linalg.inv(viewmat) @ np.vstack([cam, np.ones(len(depth))]))[:3].T


def visible_fraction(points: np.ndarray, viewmats: np.ndarray, Ks: np.ndarray,
                     widths: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """Fraction of cameras whose image contains each point (in front of the camera)."""
    hits = np.zeros(len(points))
    for v, k, w, h in zip(viewmats, Ks, widths, heights):
        u, vv, _, ahead = project(points, v, k)
        hits += ahead & (u >= 0) & (u < w) & (vv >= 0) & (vv < h)
    return hits / max(len(viewmats), 1)


IN_VIEW_FRACTION = 0.3
"""The share of the cameras a random starting point must be seen by (``sample_in_view``)."""


@dataclass(frozen=True)
class InViewPoints:
    """Random starting points, and how many of them no ``min_fraction`` of the cameras sees."""

    points: np.ndarray
    unseen: int


def sample_in_view(bounds: SceneBounds, n: int, viewmats: np.ndarray, Ks: np.ndarray,
                   widths: np.ndarray, heights: np.ndarray, rng: np.random.Generator,
                   min_fraction: float = IN_VIEW_FRACTION) -> InViewPoints:
    """Uniform points in the bounds box that at least ``min_fraction`` of the cameras see.

    Rejection sampling keeps random initialisation (3DGS's synthetic-scene default) from
    wasting Gaussians where no camera can constrain them. When 50 rounds find too few (cameras
    that barely overlap the box), the rest are uniform in the box, and ``unseen`` counts them so
    the caller can say so.
    """
    out: list[np.ndarray] = []
    total = 0
    for _ in range(50):
        cand = bounds.center + rng.uniform(-1.0, 1.0, size=(4 * n, 3)) * bounds.half_size
        keep = cand[visible_fraction(cand, viewmats, Ks, widths, heights) >= min_fraction]
        out.append(keep)
        total += len(keep)
        if total >= n:
            break
    pts = np.concatenate(out) if out else np.zeros((0, 3))
    unseen = max(n - len(pts), 0)
    if unseen:
        pts = np.concatenate([pts, bounds.center + rng.uniform(-1.0, 1.0, size=(unseen, 3)) * bounds.half_size])
    return InViewPoints(pts[:n], unseen)
