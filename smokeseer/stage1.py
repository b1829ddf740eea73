"""Stage 1: poses, masks, and one world frame for both cameras.

Poses and masks come from the dataset. When a capture's RGB and thermal poses were solved
separately, the thermal poses are mapped into the RGB frame by the Sim(3) between the two
camera-centre trajectories. Optional pose noise perturbs training poses for robustness studies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from smokeseer.cameras import SceneBounds, camera_center, scene_bounds
from smokeseer.config import TrainConfig
from smokeseer.data import ModalityData, SceneData
from smokeseer.registration import Sim3, register_trajectories


@dataclass
class Stage1Report:
    """What Stage 1 decided, for the log and metrics.json."""

    registered: bool
    sim3_scale: float
    registration_rmse: float | None
    registration_inliers: int | None
    pose_noise: bool
    bounds: SceneBounds


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / max(np.linalg.norm(axis), 1e-12)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def perturb_poses(mod: ModalityData, rot_deg: float, trans: float, rng: np.random.Generator) -> None:
    """Add Gaussian pose noise to training frames: a rotation about a random axis with angle
    ~ N(0, rot_deg) and a camera-centre shift ~ N(0, trans) per axis (scene units)."""
    for f in mod.frames:
        if f.split != "train":
            continue
        r, c = f.viewmat[:3, :3], camera_center(f.viewmat)
        dr = _rotation(rng.normal(size=3), math.radians(rng.normal(0.0, rot_deg))) if rot_deg > 0 else np.eye(3)
        c = c + (rng.normal(0.0, trans, size=3) if trans > 0 else 0.0)
        new_r = dr @ r
        f.viewmat = np.eye(4)
        f.viewmat[:3, :3] = new_r
        f.viewmat[:3, 3] = -new_r @ c


def _needs_registration(cfg: TrainConfig, scene: SceneData) -> bool:
    """Synthetic datasets share one world frame; a real capture says so in capture.json
    (``"pose_frames": "separate"``) or the user forces ``registration=trajectory``."""
    if scene.thermal is None or cfg.registration == "off":
        return False
    if cfg.registration == "trajectory":
        return True
    return not scene.synthetic and scene.meta.get("pose_frames") == "separate"


def run_stage1(cfg: TrainConfig, scene: SceneData) -> Stage1Report:
    """Register, perturb, and bound the scene, editing ``scene``'s poses in place."""
    registered, scale, rmse, inliers = False, 1.0, None, None
    if _needs_registration(cfg, scene) and scene.thermal is not None:
        src = np.stack([camera_center(f.viewmat) for f in scene.thermal.frames])
        dst = np.stack([camera_center(f.viewmat) for f in scene.rgb.frames])
        res = register_trajectories(src, np.array([f.timestamp_s for f in scene.thermal.frames]),
                                    dst, np.array([f.timestamp_s for f in scene.rgb.frames]), seed=cfg.seed)
        _apply(res.sim3, scene.thermal)
        registered, scale, rmse, inliers = True, res.sim3.scale, res.rmse, int(res.inliers.sum())
    mods = [scene.rgb] + ([scene.thermal] if scene.thermal is not None else [])
    train = [f for m in mods for f in m.frames if f.split == "train"]
    bounds = scene_bounds(np.stack([f.viewmat for f in train]), np.stack([f.K for f in train]),
                          np.array([f.width for f in train]))
    noisy = cfg.pose_noise_rot_deg > 0 or cfg.pose_noise_trans > 0
    if noisy:
        rng = np.random.default_rng(cfg.seed + 7)
        for m in mods:
            perturb_poses(m, cfg.pose_noise_rot_deg, cfg.pose_noise_trans * bounds.extent, rng)
    return Stage1Report(registered, scale, rmse, inliers, noisy, bounds)


def _apply(sim: Sim3, mod: ModalityData) -> None:
    for f in mod.frames:
        f.viewmat = sim.transform_viewmat(f.viewmat)
