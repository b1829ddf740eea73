"""Cross-modal registration: the Sim(3) that maps thermal poses into the RGB frame.

RGB and thermal cameras share a rig, so their camera centres trace the same trajectory up to
a similarity when each modality was posed separately (e.g. two SfM runs). Pairing centres by
nearest timestamp gives 3D-3D correspondences with no cross-modal feature matching; Umeyama
solves the similarity in closed form and RANSAC rejects pairs broken by bad poses.
"""
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

    def matrix(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = self.translation
        return m

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


@dataclass
class RansacResult:
    sim3: Sim3
    inliers: np.ndarray
    rmse: float


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


def ransac_sim3(src: np.ndarray, dst: np.ndarray, threshold: float, iterations: int = 500,
                seed: int = 0, with_scale: bool = True) -> RansacResult:
    """Robust Sim(3): minimal 3-point hypotheses, the largest inlier set wins, then a refit.

    ``threshold`` is the inlier distance in dst units.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"src/dst: need matching N×3 arrays, got {src.shape} and {dst.shape}")
    if threshold <= 0:
        raise ValueError(f"threshold: must be > 0, got {threshold}")
    n = len(src)
    if n < 3:
        raise ValueError(f"src: need at least 3 correspondences, got {n}")
    rng = np.random.default_rng(seed)
    best = np.zeros(n, dtype=bool)
    best_err = np.inf
    for _ in range(iterations):
        idx = rng.choice(n, size=3, replace=False)
        a = src[idx]
        if np.linalg.norm(np.cross(a[1] - a[0], a[2] - a[0])) < 1e-12:
            continue
        try:
            model = umeyama(a, dst[idx], with_scale)
        except ValueError:
            continue
        err = np.linalg.norm(model.apply(src) - dst, axis=1)
        inl = err < threshold
        score = float(err[inl].sum()) if inl.any() else np.inf
        if inl.sum() > best.sum() or (inl.sum() == best.sum() and score < best_err):
            best, best_err = inl, score
    if best.sum() < 3:
        model = umeyama(src, dst, with_scale)
        best = np.ones(n, dtype=bool)
    else:
        model = umeyama(src[best], dst[best], with_scale)
        err = np.linalg.norm(model.apply(src) - dst, axis=1)
        refined = err < threshold
        if refined.sum() >= 3:
            best = refined
            model = umeyama(src[best], dst[best], with_scale)
    rmse = float(np.sqrt(np.mean(np.linalg.norm(model.apply(src[best]) - dst[best], axis=1) ** 2)))
    return RansacResult(sim3=model, inliers=best, rmse=rmse)


def pair_by_timestamp(times_a: np.ndarray, times_b: np.ndarray,
                      max_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i into a, j into b) where b[j] is a's nearest timestamp within max_dt."""
    times_a = np.asarray(times_a, dtype=np.float64)
    times_b = np.asarray(times_b, dtype=np.float64)
    if len(times_a) == 0 or len(times_b) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    gap = np.abs(times_a[:, None] - times_b[None, :])
    j = gap.argmin(axis=1)
    ok = gap[np.arange(len(times_a)), j] <= max_dt
    return np.nonzero(ok)[0], j[ok]


def register_trajectories(centres_src: np.ndarray, times_src: np.ndarray,
                          centres_dst: np.ndarray, times_dst: np.ndarray,
                          max_dt: float | None = None, inlier_fraction: float = 0.05,
                          seed: int = 0) -> RansacResult:
    """Sim(3) from the src trajectory to the dst trajectory, pairing by nearest timestamp.

    The inlier threshold is ``inlier_fraction`` of the dst trajectory's extent, since the two
    cameras are unsynchronised and a pair's centres differ by up to half a frame of motion.
    """
    if max_dt is None:
        steps = np.diff(np.sort(np.asarray(times_dst, dtype=np.float64)))
        max_dt = float(np.median(steps)) if len(steps) else np.inf
    ia, jb = pair_by_timestamp(times_src, times_dst, max_dt)
    if len(ia) < 3:
        raise ValueError(f"times: only {len(ia)} timestamp pairs within {max_dt:.4g} s; need 3")
    dst = np.asarray(centres_dst)[jb]
    extent = float(np.linalg.norm(dst - dst.mean(0), axis=1).max())
    threshold = max(inlier_fraction * extent, 1e-9)
    return ransac_sim3(np.asarray(centres_src)[ia], dst, threshold=threshold, seed=seed)
