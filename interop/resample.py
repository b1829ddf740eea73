"""Resample an image to new pinhole intrinsics with the same camera centre and orientation.

The official SmokeSeer reader keeps only the field of view and puts the principal point at the
image centre (and, for its Blender layout, uses one focal length for both axes). A frame whose
intrinsics differ is warped onto such a camera instead of being silently misread.
"""
from __future__ import annotations

import numpy as np


def needs_resample(k: np.ndarray, width: int, height: int, square: bool, tol_px: float = 1e-6) -> bool:
    off_centre = abs(k[0, 2] - width / 2) > tol_px or abs(k[1, 2] - height / 2) > tol_px
    return off_centre or (square and abs(k[0, 0] - k[1, 1]) > tol_px)


def centred_intrinsics(k: np.ndarray, width: int, height: int, square: bool) -> np.ndarray:
    fx = float(k[0, 0])
    fy = fx if square else float(k[1, 1])
    return np.array([[fx, 0.0, width / 2], [0.0, fy, height / 2], [0.0, 0.0, 1.0]])


def warp_to_intrinsics(img: np.ndarray, k_src: np.ndarray, k_dst: np.ndarray,
                       nearest: bool = False) -> tuple[np.ndarray, float]:
    """``img`` (H×W or H×W×C) seen by ``k_dst`` at the same size; returns it and the fraction of
    pixels that fell outside the source (filled with 0). Pixel centres sit at +0.5."""
    h, w = img.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    x = (u + 0.5 - k_dst[0, 2]) / k_dst[0, 0]
    y = (v + 0.5 - k_dst[1, 2]) / k_dst[1, 1]
    us = k_src[0, 0] * x + k_src[0, 2] - 0.5
    vs = k_src[1, 1] * y + k_src[1, 2] - 0.5
    inside = (us >= -0.5) & (us <= w - 0.5) & (vs >= -0.5) & (vs <= h - 0.5)
    src = img.astype(np.float64)
    if nearest:
        out = src[np.clip(np.round(vs).astype(int), 0, h - 1), np.clip(np.round(us).astype(int), 0, w - 1)]
    else:
        u0 = np.clip(np.floor(us).astype(int), 0, w - 1)
        v0 = np.clip(np.floor(vs).astype(int), 0, h - 1)
        u1, v1 = np.clip(u0 + 1, 0, w - 1), np.clip(v0 + 1, 0, h - 1)
        fu = np.clip(us - u0, 0.0, 1.0)
        fv = np.clip(vs - v0, 0.0, 1.0)
        if src.ndim == 3:
            fu, fv = fu[..., None], fv[..., None]
        top = src[v0, u0] * (1 - fu) + src[v0, u1] * fu
        bottom = src[v1, u0] * (1 - fu) + src[v1, u1] * fu
        out = top * (1 - fv) + bottom * fv
    mask = inside if out.ndim == 2 else inside[..., None]
    return np.where(mask, out, 0.0), float(1.0 - inside.mean())
