"""Similarity transforms x ↦ s·R·x + t and their least-squares fit: shared by Stage 1's
cross-modal registration and the rig's thermal poses (``scenes.rig``)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Sim3:
    """x ↦ s·R·x + t."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        return self.scale * points @ self.rotation.T + self.translation

    def transform_viewmat(self, viewmat: np.ndarray) -> np.ndarray:
        """Move an OpenCV world-to-camera matrix into the target frame (units follow s)."""
        r, t = viewmat[:3, :3], viewmat[:3, 3]
        centre = -r.T @ t
        new_r = r @ self.rotation.T
        new_c = self.apply(centre[None])[0]
        out = np.eye(4)
        out[:3, :3] = new_r
        out[:3, 3] = -new_r @ new_c
        return out


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Sim3:
    """Least-squares similarity with dst ≈ s·R·src + t (Umeyama 1991, closed form via SVD)."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"src/dst: need matching N×3 arrays, got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise ValueError(f"src: need at least 3 correspondences, got {len(src)}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise ValueError("src/dst: correspondences contain NaN or Inf")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = (xs ** 2).sum() / len(src)
    if var_s < 1e-18:
        raise ValueError("src: points are all at one location; the similarity is undetermined")
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    r = u @ sign @ vt
    s = float(np.trace(np.diag(d) @ sign) / var_s) if with_scale else 1.0
    t = mu_d - s * r @ mu_s
    return Sim3(scale=s, rotation=r, translation=t)
