"""Stage 1: poses, masks, and one world frame for both cameras.

Poses come from the dataset, or from the images alone (``poses=sfm``: structure from motion and
the rig, ``poses_from_images``). When a capture's RGB and thermal poses were solved separately,
the thermal poses are mapped into the RGB frame by the rig registration (orientations, centres
and the lever arm; ``registration.register_rig``), and what it found is reported. Masks come
from the dataset, from an external segmenter's files (``mask_dir``), or are estimated from the
images (``stage1=estimate``), which then also decides from the data whether there is smoke
(``smoke_presence``: what the posed RGB frames' multi-view consistency cannot explain).
Optional pose noise perturbs training poses for robustness studies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from scenes.cameras import SceneBounds, camera_center, scene_bounds
from scenes.capture import CAPTURE_FILE
from scenes.generated import spec_rig
from scenes.images import load_masks
from scenes.rig import RigExtrinsic, parse_rig
from scenes.scene import ModalityData, SceneData
from scenes.similarity import Sim3
from smokeseer.config import TrainConfig
from smokeseer.config.streams import numpy_stream
from smokeseer.stage1.poses_from_images import pose_from_images
from smokeseer.stage1.registration import register_rig
from smokeseer.stage1.smoke_presence import ESTIMATOR, decide_smoke_presence
from smokeseer.stage1.sparse_points import SparsePoints, sparse_points


@dataclass
class Stage1Report:
    """What Stage 1 decided, for the log and metrics.json."""

    registered: bool
    sim3_scale: float
    registration_rmse: float | None
    registration_inliers: int | None
    pose_noise: bool
    bounds: SceneBounds
    registration: dict[str, Any] | None = None
    masks: str = "dataset"
    notes: list[str] = field(default_factory=list)
    start_points: SparsePoints | None = None
    """Stage 2's starting points from the training frames (``stage2.init_from=images`` on a
    dataset with no points of its own); ``bounds`` is then their box."""


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
    if scene.thermal is None or cfg.registration == "off" or cfg.poses == "sfm":
        return False
    if cfg.registration == "trajectory":
        return True
    return not scene.synthetic and scene.meta.get("pose_frames") == "separate"


def run_stage1(cfg: TrainConfig, scene: SceneData) -> Stage1Report:
    """Register, choose the masks, perturb, and bound the scene, editing ``scene`` in place."""
    notes = list(scene.notes)
    if cfg.poses == "sfm":
        if scene.poses is None:
            notes += pose_from_images(scene, _given_rig(scene))
        else:
            notes.append("poses=sfm: the capture's poses already come from its images (see above)")
    registered, scale, rmse, inliers, registration = False, 1.0, None, None, None
    if _needs_registration(cfg, scene) and scene.thermal is not None:
        th, rgb = scene.thermal.frames, scene.rgb.frames
        lever = np.asarray(cfg.registration_lever_arm, dtype=np.float64) if cfg.registration_lever_arm else None
        res = register_rig(np.stack([f.viewmat for f in th]), np.array([f.timestamp_s for f in th]),
                           np.stack([f.viewmat for f in rgb]), np.array([f.timestamp_s for f in rgb]),
                           lever_arm=lever)
        _apply(res.sim3, scene.thermal)
        registration = res.to_dict()
        registered, scale, rmse, inliers = True, res.sim3.scale, res.centre_rmse, int(res.inliers.sum())
        notes += [f"registration: {n}" for n in res.notes]
    masks = _choose_masks(cfg, scene, notes)
    mods = [scene.rgb] + ([scene.thermal] if scene.thermal is not None else [])
    train = [f for m in mods for f in m.frames if f.split == "train"]
    bounds = scene_bounds(np.stack([f.viewmat for f in train]), np.stack([f.K for f in train]),
                          np.array([f.width for f in train]))
    noisy = cfg.pose_noise_rot_deg > 0 or cfg.pose_noise_trans > 0
    if noisy:
        rng = numpy_stream(cfg.seed, "stage1.pose-noise")
        for m in mods:
            perturb_poses(m, cfg.pose_noise_rot_deg, cfg.pose_noise_trans * bounds.extent, rng)
    start = None
    if cfg.stage2.init_from == "images" and scene.init_points is None:
        start = sparse_points(scene)
        notes.append(f"stage 2 start: {start.note}")
        if start.points is not None:
            bounds = scene_bounds(np.stack([f.viewmat for f in train]), np.stack([f.K for f in train]),
                                  np.array([f.width for f in train]), start.points)
    return Stage1Report(registered, scale, rmse, inliers, noisy, bounds, registration, masks, notes, start)


def _given_rig(scene: SceneData) -> RigExtrinsic | None:
    """The RGB→thermal extrinsic a calibration gives: a generated dataset's rig, or a capture's
    ``rig`` in capture.json (None without one: the rig module then says what it assumes)."""
    if scene.thermal is None:
        return None
    if scene.synthetic:
        return spec_rig(scene.path)
    return parse_rig(scene.meta, scene.path / CAPTURE_FILE)


def _choose_masks(cfg: TrainConfig, scene: SceneData, notes: list[str]) -> str:
    """Replace the dataset's masks when asked; returns where the masks came from."""
    rgb = scene.rgb
    if cfg.mask_dir:
        files = [Path(cfg.mask_dir) / f"{f.file_stem}.png" for f in rgb.frames]
        factor = _mask_factor(files, rgb.frames[0].width)
        rgb.masks = load_masks(files, factor, cfg.mask_dir, notes)
        if rgb.masks is None:
            raise ValueError(f"mask_dir: {cfg.mask_dir} has no NAME.png mask for any RGB frame")
        notes.append(f"masks: loaded from {cfg.mask_dir} (external segmenter)")
        return f"files: {cfg.mask_dir}"
    if cfg.stage1 != "estimate":
        return "dataset" if rgb.masks is not None else "none"
    train = rgb.indices("train")
    presence = decide_smoke_presence(rgb.images, rgb.frames, train)
    said = scene.smoke_present
    scene.smoke_present = presence.present
    scene.smoke_static = False
    rgb.masks = presence.masks if presence.present else np.zeros_like(presence.masks)
    notes.append(f"smoke presence from the data: the multi-view residual of the RGB training frames (median of the "
                 f"per-frame medians) is {presence.statistic:.3f} times the smoke-free floor against a threshold of "
                 f"{presence.threshold}, so smoke is {'present' if presence.present else 'absent'} "
                 f"(the dataset said present={said})")
    notes += presence.notes
    notes.append(f"masks: estimated from the RGB frames ({ESTIMATOR}: residual above the smoke-free floor), covering "
                 f"{100 * float(rgb.masks[train].mean()):.1f} % of the training pixels"
                 + ("" if presence.present else " (empty: no smoke)")
                 + "; static smoke cannot be told from a moving camera's masks, so the deformation network stays on")
    return f"estimated: {ESTIMATOR}"


def _mask_factor(files: list[Path], width: int) -> int:
    """External masks are stored at the capture's resolution; the factor brings them to ours."""
    from PIL import Image

    for p in files:
        if p.is_file():
            with Image.open(p) as im:
                mask_width = im.size[0]
            if mask_width % width:
                raise ValueError(f"{p}: mask is {mask_width} px wide, not a multiple of the working width {width}")
            return mask_width // width
    return 1


def _apply(sim: Sim3, mod: ModalityData) -> None:
    for f in mod.frames:
        f.viewmat = sim.transform_viewmat(f.viewmat)
