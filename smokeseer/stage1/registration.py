"""Cross-modal registration: the Sim(3) that maps thermal poses into the RGB frame.

RGB and thermal cameras share a rig, so their camera centres trace the same trajectory up to
a similarity when each modality was posed separately (e.g. two SfM runs). Pairing centres by
nearest timestamp gives 3D-3D correspondences with no cross-modal feature matching; Umeyama
solves the similarity in closed form and RANSAC rejects pairs broken by bad poses.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, RotationSpline, Slerp

from scenes.similarity import Sim3, umeyama


@dataclass
class RansacResult:
    sim3: Sim3
    inliers: np.ndarray
    rmse: float


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
        raise ValueError(f"registration: no 3 correspondences agree within {threshold:.4g} (best hypothesis had "
                         f"{int(best.sum())} of {n} inliers); the trajectories do not match up to a similarity")
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


# ----------------------------------------------------------------------------- rig registration

STRAIGHT_LINE_RATIO = 0.01
"""A path whose second principal extent is below this fraction of its first is a straight line."""


@dataclass
class RigRegistration:
    """The Sim(3) from the thermal poses' frame to the RGB frame, and how it was found."""

    sim3: Sim3
    lever_arm: np.ndarray
    lever_source: str
    pairs: int
    inliers: np.ndarray
    centre_rmse: float
    centre_max: float
    rotation_rms_deg: float
    geometry: str
    centres_only_disagreement_deg: float | None
    notes: list[str]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready report for metrics.json."""
        rot = Rotation.from_matrix(self.sim3.rotation)
        rotvec = rot.as_rotvec()
        angle = float(np.linalg.norm(rotvec))
        return {
            "scale": self.sim3.scale,
            "rotation_matrix": self.sim3.rotation.tolist(),
            "rotation_angle_deg": math.degrees(angle),
            "rotation_axis": (rotvec / angle).tolist() if angle > 0 else [0.0, 0.0, 0.0],
            "translation": self.sim3.translation.tolist(),
            "lever_arm": self.lever_arm.tolist(), "lever_arm_source": self.lever_source,
            "pairs": self.pairs, "inliers": int(self.inliers.sum()),
            "centre_rmse": self.centre_rmse, "centre_max_residual": self.centre_max,
            "rotation_rms_deg": self.rotation_rms_deg, "geometry": self.geometry,
            "centres_only_disagreement_deg": self.centres_only_disagreement_deg, "notes": self.notes,
        }


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = (np.trace(a.T @ b) - 1.0) / 2.0
    return math.degrees(math.acos(float(np.clip(c, -1.0, 1.0))))


def _chordal_mean(rots: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(rots.sum(axis=0))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return u @ d @ vt


def interpolate_poses(viewmats: np.ndarray, times: np.ndarray,
                      at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera rotations and camera centres at the times ``at`` (within ``times``' range):
    the RGB pose at each thermal frame's instant. Cubic splines, since a linear blend cuts the
    corners of a curved path and biases the registered scale (0.3 % on a 12 fps orbit)."""
    order = np.argsort(times)
    t = np.asarray(times, dtype=np.float64)[order]
    v = np.asarray(viewmats)[order]
    centres = np.stack([-m[:3, :3].T @ m[:3, 3] for m in v])
    if len(t) == 1:
        return np.repeat(v[:1, :3, :3], len(at), axis=0), np.repeat(centres[:1], len(at), axis=0)
    if len(t) < 4:
        rots = Slerp(t, Rotation.from_matrix(v[:, :3, :3]))(at).as_matrix()
        return rots, np.stack([np.interp(at, t, centres[:, k]) for k in range(3)], axis=1)
    from scipy.interpolate import CubicSpline  # here: scipy.interpolate takes ~0.1 s to import, and only registered rigs need it

    rots = RotationSpline(t, Rotation.from_matrix(v[:, :3, :3]))(at).as_matrix()
    return rots, CubicSpline(t, centres, axis=0)(at)


def register_rig(src_viewmats: np.ndarray, src_times: np.ndarray, dst_viewmats: np.ndarray,
                 dst_times: np.ndarray, lever_arm: np.ndarray | None = None,
                 rig_rotation: np.ndarray | None = None, max_dt: float | None = None,
                 rot_threshold_deg: float = 2.0) -> RigRegistration:
    """Sim(3) mapping the src camera's frame (thermal, solved on its own) into the dst frame
    (RGB), for two cameras fixed to one rig.

    Orientations fix the rotation: with the rig rotation R_rig (identity by default, the cameras
    looking the same way), each src frame gives R = R_dst(t)ᵀ R_rigᵀ R_src from the dst pose
    interpolated at its instant; a consensus of those is averaged. Scale and translation then
    come from the centres by least squares, with the thermal camera ``lever_arm`` away from the
    RGB camera (dst camera axes, OpenCV, dst units) when given. (Estimating the lever is not
    attempted: on a look-at orbit a lever along the optical axis moves every camera onto the
    target and the fit collapses.) A straight-line path is therefore registered from its
    orientations; a camera that never moves is refused (no scale).
    """
    src_viewmats, dst_viewmats = np.asarray(src_viewmats, float), np.asarray(dst_viewmats, float)
    src_times, dst_times = np.asarray(src_times, float), np.asarray(dst_times, float)
    notes: list[str] = []
    if max_dt is None:
        steps = np.diff(np.sort(dst_times))
        max_dt = float(np.median(steps)) if len(steps) else 0.0
    lo, hi = dst_times.min(), dst_times.max()
    usable = (src_times >= lo - max_dt) & (src_times <= hi + max_dt)
    if usable.sum() < 3:
        raise ValueError(f"registration: only {int(usable.sum())} thermal frames fall within the RGB frames' times "
                         f"[{lo:.4g}, {hi:.4g}] s (± {max_dt:.4g} s); need 3 (check the timestamps)")
    if (~usable).any():
        notes.append(f"{int((~usable).sum())} thermal frames outside the RGB time range are not used to register")
    idx = np.nonzero(usable)[0]
    r_dst, c_dst = interpolate_poses(dst_viewmats, dst_times, np.clip(src_times[idx], lo, hi))
    r_src = src_viewmats[idx, :3, :3]
    c_src = np.stack([-m[:3, :3].T @ m[:3, 3] for m in src_viewmats[idx]])
    r_rig = np.eye(3) if rig_rotation is None else np.asarray(rig_rotation, float)
    per_pair = np.stack([rd.T @ r_rig.T @ rs for rd, rs in zip(r_dst, r_src)])
    support = [[_angle_deg(a, b) < rot_threshold_deg for b in per_pair] for a in per_pair]
    best = int(np.argmax([sum(s) for s in support]))
    rot_ok = np.array(support[best])
    rotation = _chordal_mean(per_pair[rot_ok])

    spread = np.linalg.svd(c_src - c_src.mean(0), compute_uv=False)
    if spread[0] < 1e-9 * max(1.0, float(np.abs(c_src).max())):
        raise ValueError("registration: the thermal camera centres do not move; the scale between the two pose "
                         "frames is unobservable (use pose_frames: shared, or registration=off)")
    geometry = "straight line" if spread[1] < STRAIGHT_LINE_RATIO * spread[0] else "general"
    if geometry == "straight line":
        notes.append("straight-line path: the rotation about the path comes from the camera orientations "
                     f"(rig rotation {'given' if rig_rotation is not None else 'assumed identity'}); "
                     "a centre-only fit cannot determine it")

    inliers = rot_ok & _centre_consensus(rotation, c_src, c_dst, rot_ok)
    lever = np.zeros(3) if lever_arm is None else np.asarray(lever_arm, dtype=np.float64)
    if lever_arm is None:
        notes.append("no lever arm given: the thermal camera is taken to sit at the RGB camera's centre, so the "
                     "translation is off by up to the rig's offset (set registration_lever_arm)")
    extent = float(np.linalg.norm(c_dst - c_dst.mean(0), axis=1).max())
    for _ in range(3):
        sel = np.nonzero(inliers)[0]
        if len(sel) < 3:
            raise ValueError(f"registration: only {len(sel)} of {len(idx)} thermal frames agree with the RGB "
                             "trajectory; need 3 (bad poses or timestamps?)")
        scale, trans = _solve_scale_translation(rotation, c_src[sel], c_dst[sel], r_dst[sel], lever)
        resid = np.linalg.norm(scale * c_src @ rotation.T + trans - (c_dst + np.einsum("nji,j->ni", r_dst, lever)),
                               axis=1)
        limit = max(5.0 * float(np.median(resid[inliers])), 0.02 * extent, 1e-9)
        new = rot_ok & (resid < limit)
        if np.array_equal(new, inliers):
            break
        inliers = new
    sim = Sim3(scale=scale, rotation=rotation, translation=trans)
    centres_only = None
    if geometry == "general":
        target = c_dst + np.einsum("nji,j->ni", r_dst, lever)
        centres_only = _angle_deg(umeyama(c_src[inliers], target[inliers]).rotation, rotation)
        if centres_only > rot_threshold_deg:
            notes.append(f"orientations and centres disagree by {centres_only:.2f} deg: is the rig rotation "
                         "really the identity?")
    rot_resid = [_angle_deg(p, rotation) for p in per_pair[inliers]]
    res = resid[inliers]
    return RigRegistration(sim3=sim, lever_arm=lever, lever_source="given" if lever_arm is not None else "none",
                           pairs=len(idx),
                           inliers=inliers, centre_rmse=float(np.sqrt(np.mean(res ** 2))),
                           centre_max=float(res.max()),
                           rotation_rms_deg=float(np.sqrt(np.mean(np.square(rot_resid)))),
                           geometry=geometry, centres_only_disagreement_deg=centres_only, notes=notes)


def _solve_scale_translation(rotation: np.ndarray, c_src: np.ndarray, c_dst: np.ndarray, r_dst: np.ndarray,
                             lever: np.ndarray) -> tuple[float, np.ndarray]:
    """Least squares for s and t in s·R·c_src + t = c_dst + R_dstᵀ ℓ (ℓ the lever arm)."""
    a = np.concatenate([np.concatenate([(rotation @ c)[:, None], np.eye(3)], axis=1) for c in c_src])
    b = (c_dst + np.einsum("nji,j->ni", r_dst, lever)).reshape(-1)
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    return float(x[0]), x[1:4]


def _centre_consensus(rotation: np.ndarray, c_src: np.ndarray, c_dst: np.ndarray, candidates: np.ndarray,
                      hypotheses: int = 300, fraction: float = 0.05) -> np.ndarray:
    """With the rotation known, two pairs fix scale and translation: keep the largest set of
    pairs that agree within ``fraction`` of the trajectory's extent, so broken poses cannot pull
    the least-squares fit."""
    idx = np.nonzero(candidates)[0]
    extent = float(np.linalg.norm(c_dst - c_dst.mean(0), axis=1).max())
    limit = max(fraction * extent, 1e-9)
    rng = np.random.default_rng(0)
    src_rot = c_src @ rotation.T
    best = np.zeros(len(c_src), dtype=bool)
    for _ in range(hypotheses):
        i, j = rng.choice(idx, size=2, replace=False)
        d_src, d_dst = src_rot[i] - src_rot[j], c_dst[i] - c_dst[j]
        if d_src @ d_src < 1e-18:
            continue
        scale = float(d_src @ d_dst / (d_src @ d_src))
        if scale <= 0:
            continue
        trans = c_dst[i] - scale * src_rot[i]
        ok = candidates & (np.linalg.norm(scale * src_rot + trans - c_dst, axis=1) < limit)
        if ok.sum() > best.sum():
            best = ok
    if best.sum() < 3:
        raise ValueError(f"registration: no 3 camera centres agree on one scale and shift within {limit:.4g} "
                         "(the trajectories do not match up to a similarity)")
    return best
