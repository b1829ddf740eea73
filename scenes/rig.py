"""Thermal poses from the rig: the RGB trajectory at each thermal instant, then the fixed extrinsic.

The two cameras are bolted to one body, so a thermal pose needs no thermal features: SLERP the
RGB camera's rotation and interpolate its centre linearly between the two RGB frames around
the thermal timestamp, then move from the RGB camera to the thermal camera by the extrinsic
(rotation and lever arm) that ``capture.json`` → ``rig`` gives. All matrices are OpenCV
world-to-camera (x right, y down, z forward).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from contracts.errors import DatasetError
from scenes.similarity import umeyama


@dataclass(frozen=True)
class RigExtrinsic:
    """Thermal camera in RGB camera axes: ``x_rgb = rotation · x_thermal + lever_arm``.

    ``lever_arm`` is the thermal camera centre in the RGB camera's axes, in metres;
    ``metres_per_unit`` is how long one pose unit is (1 for metric poses; SfM poses have an
    arbitrary scale, so the lever is applied only when it is known)."""

    rotation: np.ndarray
    lever_arm_m: np.ndarray
    metres_per_unit: float | None = None

    @property
    def applies_lever(self) -> bool:
        """Whether the thermal centres are moved by the lever: it is non-zero and the poses' scale is known."""
        return self.metres_per_unit is not None and bool(self.lever_arm_m.any())

    def lever_in_units(self) -> np.ndarray | None:
        """The lever arm in pose units, or None when the poses' scale is unknown."""
        return None if self.metres_per_unit is None else self.lever_arm_m / self.metres_per_unit


def parse_rig(meta: dict[str, Any], source: Path) -> RigExtrinsic | None:
    """``capture.json`` → ``rig``: ``{"thermal_rotation": 3×3, "lever_arm_m": [x, y, z],
    "metres_per_unit": s}`` (rotation and units optional: identity and unknown). None without it."""
    rig = meta.get("rig")
    if rig is None:
        return None
    if not isinstance(rig, dict):
        raise DatasetError(f"{source}: field 'rig' must be an object")
    rot = np.asarray(rig.get("thermal_rotation", np.eye(3).tolist()), dtype=object)
    try:
        rotation = np.asarray(rot.tolist(), dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{source}: field 'rig.thermal_rotation' must be a 3x3 matrix of numbers") from None
    if rotation.shape != (3, 3) or not np.all(np.isfinite(rotation)):
        raise DatasetError(f"{source}: field 'rig.thermal_rotation' must be a 3x3 matrix of finite numbers")
    if np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-4 or np.linalg.det(rotation) < 0:
        raise DatasetError(f"{source}: field 'rig.thermal_rotation' is not a rotation (orthonormal, det +1)")
    if "lever_arm_m" not in rig:
        raise DatasetError(f"{source}: field 'rig.lever_arm_m' is missing (thermal centre in RGB camera axes, metres)")
    try:
        lever = np.asarray(rig["lever_arm_m"], dtype=np.float64)
    except (TypeError, ValueError):
        lever = np.zeros(0)
    if lever.shape != (3,) or not np.all(np.isfinite(lever)):
        raise DatasetError(f"{source}: field 'rig.lever_arm_m' must be 3 finite numbers")
    units = rig.get("metres_per_unit")
    if units is not None and (not isinstance(units, (int, float)) or isinstance(units, bool) or not units > 0):
        raise DatasetError(f"{source}: field 'rig.metres_per_unit' must be a positive number")
    return RigExtrinsic(rotation, lever, None if units is None else float(units))


def slerp(r0: np.ndarray, r1: np.ndarray, w: float) -> np.ndarray:
    """The rotation a fraction ``w`` of the way from ``r0`` to ``r1`` along the shortest arc."""
    rel = r0.T @ r1
    angle = float(np.arccos(np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0)))
    if angle < 1e-12:
        return r0.copy()
    if np.pi - angle < 1e-6:
        # Half-turn: the axis is the eigenvector of rel with eigenvalue +1.
        vals, vecs = np.linalg.eigh((rel + rel.T) / 2.0)
        axis = vecs[:, int(np.argmax(vals))]
    else:
        axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]]) / (2 * np.sin(angle))
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = w * angle
    return r0 @ (np.eye(3) + np.sin(a) * k + (1.0 - np.cos(a)) * k @ k)


def interpolate_trajectory(viewmats: np.ndarray, times: np.ndarray, at: np.ndarray,
                           tolerance: float = 0.0) -> np.ndarray:
    """World-to-camera matrices at the instants ``at``: SLERP of the rotations and linear
    interpolation of the camera centres between the two frames around each instant.

    An instant up to ``tolerance`` seconds outside the frames' times takes the end pose;
    further out is an error, since extrapolating a trajectory is a guess."""
    viewmats, times, at = np.asarray(viewmats, float), np.asarray(times, float), np.asarray(at, float)
    order = np.argsort(times)
    times, viewmats = times[order], viewmats[order]
    if len(times) == 0 or np.any(np.diff(times) <= 0):
        raise ValueError("interpolate_trajectory: need frames with distinct timestamps")
    centres = np.einsum("nji,nj->ni", viewmats[:, :3, :3], -viewmats[:, :3, 3])
    out = np.tile(np.eye(4), (len(at), 1, 1))
    for n, t in enumerate(at):
        if t < times[0] - tolerance or t > times[-1] + tolerance:
            raise ValueError(f"interpolate_trajectory: instant {t:.6g} s is outside the trajectory's times "
                             f"[{times[0]:.6g}, {times[-1]:.6g}] s")
        t = min(max(t, times[0]), times[-1])
        j = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, max(len(times) - 2, 0)))
        if len(times) == 1:
            rot, centre = viewmats[0, :3, :3], centres[0]
        else:
            w = (t - times[j]) / (times[j + 1] - times[j])
            rot = slerp(viewmats[j, :3, :3], viewmats[j + 1, :3, :3], w)
            centre = (1.0 - w) * centres[j] + w * centres[j + 1]
        out[n, :3, :3] = rot
        out[n, :3, 3] = -rot @ centre
    return out


def apply_extrinsic(rgb_viewmats: np.ndarray, rotation: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """Thermal world-to-camera matrices from RGB ones: ``x_thermal = Rᵀ (x_rgb − lever)`` with
    ``x_rgb = V_rgb · x_world`` (``lever`` in pose units, RGB camera axes)."""
    rgb_viewmats = np.asarray(rgb_viewmats, float)
    out = np.tile(np.eye(4), (len(rgb_viewmats), 1, 1))
    out[:, :3, :3] = rotation.T @ rgb_viewmats[:, :3, :3]
    out[:, :3, 3] = (rgb_viewmats[:, :3, 3] - lever) @ rotation
    return out


STRAIGHT_PATH_RATIO = 0.05
"""Centres whose second principal spread is below this fraction of the first lie on a line."""


@dataclass
class RigRotationEstimate:
    """The rig rotation found from a thermal SfM run, and how well the frames agree on it."""

    rotation: np.ndarray
    frames: int
    residual_deg: float
    centre_rmse: float


def estimate_rig_rotation(rgb_viewmats: np.ndarray, rgb_times: np.ndarray, thermal_viewmats: np.ndarray,
                          thermal_times: np.ndarray) -> RigRotationEstimate:
    """The thermal camera's rotation in RGB camera axes, from thermal poses solved on their own
    (their own world frame and scale): the Sim(3) between the two worlds comes from the camera
    centres (Umeyama, thermal centres onto the RGB trajectory at the thermal instants; the lever
    arm, small against the path, is neglected), then each frame gives
    ``R_rig = R_rgb · W · R_thermalᵀ`` and their chordal mean is the estimate.

    Centres on a straight line leave the rotation about the line unobservable: refused (as is
    a rotation found from relative motions alone when every motion turns about one axis, the
    drone orbit's case, which is why the centres are used)."""
    steps = np.diff(np.sort(np.asarray(rgb_times, float)))
    tolerance = 0.5 * float(np.median(steps)) if len(steps) else 0.0
    inside = (thermal_times >= np.min(rgb_times) - tolerance) & (thermal_times <= np.max(rgb_times) + tolerance)
    if inside.sum() < 3:
        raise ValueError(f"rig estimate: {int(inside.sum())} thermal frames fall within the RGB frames' times; need 3")
    rgb_at = interpolate_trajectory(rgb_viewmats, rgb_times, np.asarray(thermal_times)[inside], tolerance)
    th = np.asarray(thermal_viewmats, float)[inside]
    c_rgb = np.einsum("nji,nj->ni", rgb_at[:, :3, :3], -rgb_at[:, :3, 3])
    c_th = np.einsum("nji,nj->ni", th[:, :3, :3], -th[:, :3, 3])
    spread = np.linalg.svd(c_th - c_th.mean(0), compute_uv=False)
    if spread[1] < STRAIGHT_PATH_RATIO * spread[0]:
        raise ValueError("rig estimate: the thermal camera centres lie on a straight line, so the rotation about "
                         "the line is unobservable from them")
    fit_sim3 = umeyama(c_th, c_rgb)
    world, scale, shift = fit_sim3.rotation, fit_sim3.scale, fit_sim3.translation
    per_frame = np.einsum("nij,jk,nlk->nil", rgb_at[:, :3, :3], world, th[:, :3, :3])
    u, _, vt = np.linalg.svd(per_frame.sum(0))
    rotation = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    resid = [np.degrees(np.arccos(np.clip((np.trace(rotation.T @ r) - 1.0) / 2.0, -1.0, 1.0))) for r in per_frame]
    fit = scale * c_th @ world.T + shift - c_rgb
    return RigRotationEstimate(rotation, int(inside.sum()), float(np.median(resid)),
                               float(np.sqrt(np.mean(np.sum(fit ** 2, axis=1)))))


def thermal_from_rig(rgb_viewmats: np.ndarray, rgb_times: np.ndarray, thermal_times: np.ndarray,
                     rig: RigExtrinsic | None) -> tuple[np.ndarray, list[str]]:
    """Thermal poses at ``thermal_times`` from the RGB trajectory and the rig, with notes on
    what was assumed (no extrinsic given; lever arm not applicable at the poses' scale)."""
    notes: list[str] = []
    steps = np.diff(np.sort(np.asarray(rgb_times, float)))
    tolerance = 0.5 * float(np.median(steps)) if len(steps) else 0.0
    rgb_at = interpolate_trajectory(rgb_viewmats, rgb_times, thermal_times, tolerance)
    if rig is None:
        notes.append("rig extrinsic not given in capture.json (rig.thermal_rotation, rig.lever_arm_m) and not "
                     "estimated: the thermal camera is assumed to look the same way as the RGB camera from the "
                     "same centre (identity rotation, zero lever arm)")
        return apply_extrinsic(rgb_at, np.eye(3), np.zeros(3)), notes
    lever = rig.lever_in_units()
    if lever is None and not rig.lever_arm_m.any():
        lever = np.zeros(3)
    if lever is None:
        notes.append(f"rig lever arm {rig.lever_arm_m.tolist()} m not applied: the poses have no metric scale "
                     "(set rig.metres_per_unit), so the thermal centres are the RGB centres")
        lever = np.zeros(3)
    return apply_extrinsic(rgb_at, rig.rotation, lever), notes
