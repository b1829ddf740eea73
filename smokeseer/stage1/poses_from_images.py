"""Stage 1's poses from the images alone, for a dataset that brought its own (``poses=sfm``): the
RGB frames by structure from motion, the thermal frames from the rig.

Why: the paper's Stage 1 poses every frame from the images, and a generated dataset is where
that can be scored against the truth. Every RGB frame goes into SfM (training, validation and
test alike, as a capture's would), no smoke mask is used (the oracle's would leak the truth,
and on the standard scenes masking lost features without helping: docs/real-captures.md), and
the given intrinsics are held fixed. The given poses are then read once more, for scoring
alone: the scale of the similarity taking the SfM camera centres onto them converts the
rendered depth to the ground truth's metres.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from contracts.errors import DatasetError
from scenes.cameras import camera_center
from scenes.rig import RigExtrinsic, thermal_from_rig
from scenes.scene import ModalityData, SceneData
from scenes.sfm import SfmSettings, cache_dir, run_sfm
from scenes.similarity import umeyama


def pose_from_images(scene: SceneData, rig: RigExtrinsic | None, settings: SfmSettings = SfmSettings()) -> list[str]:
    """Replace ``scene``'s poses (in place) by SfM's and the rig's; returns the notes. Frames that
    do not register are left out, evaluation frames included, and named; too few stops the run
    (``SfmError``, one line)."""
    rgb = scene.rgb
    given = np.stack([f.viewmat for f in rgb.frames])
    same_k = all(np.allclose(f.K, rgb.frames[0].K) for f in rgb.frames)
    res = run_sfm([f.file_stem for f in rgb.frames], list(rgb.images), None,
                  rgb.frames[0].K if same_k else None, settings, cache=cache_dir())
    keep = np.nonzero(res.registered)[0]
    for i in keep:
        rgb.frames[i].viewmat = res.viewmats[i].copy()
        rgb.frames[i].K = res.K.copy()
    notes = [f"poses from SfM (pycolmap) instead of the dataset's (poses=sfm): {res.describe()}"]
    if len(keep) < len(rgb.frames):
        dropped = [f"{rgb.frames[i].file_stem} ({rgb.frames[i].split})" for i in np.nonzero(~res.registered)[0]]
        notes.append(f"sfm: left out {len(dropped)} RGB frames that did not register, so they are neither trained on "
                     f"nor scored: {', '.join(dropped)}")
        scene.rgb = rgb = subset(rgb, keep)
    centres = np.stack([camera_center(f.viewmat) for f in rgb.frames])
    scene.score_depth_scale = umeyama(centres, np.stack([camera_center(v) for v in given[keep]])).scale
    notes.append(f"depth is scored at {scene.score_depth_scale:.6g} dataset units per SfM unit (the similarity of the "
                 "SfM camera centres onto the dataset's; the dataset's poses are read for this score alone)")
    scene.init_points = res.points
    scene.poses = {"rgb": res.record()}
    if scene.thermal is not None:
        notes += _thermal(scene, rig)
    return notes


def _thermal(scene: SceneData, rig: RigExtrinsic | None) -> list[str]:
    """The thermal frames at their timestamps on the SfM trajectory, moved by the rig."""
    rgb, th = scene.rgb, scene.thermal
    assert th is not None
    try:
        views, notes = thermal_from_rig(np.stack([f.viewmat for f in rgb.frames]),
                                        np.array([f.timestamp_s for f in rgb.frames]),
                                        np.array([f.timestamp_s for f in th.frames]), rig)
    except ValueError as exc:
        raise DatasetError(f"{scene.path}: thermal poses from the rig: {exc}") from None
    for f, v in zip(th.frames, views):
        f.viewmat = v
    scene.poses = {**(scene.poses or {}), "thermal": {
        "source": "rig", "extrinsic": "given" if rig is not None else "assumed (identity, zero lever arm)",
        "lever_applied": rig is not None and rig.applies_lever}}
    return [f"thermal: {n}" for n in notes]


def subset(mod: ModalityData, keep: np.ndarray) -> ModalityData:
    """``mod`` with only the frames ``keep`` (indices), every per-frame array cut alike."""
    def cut(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else a[keep]

    return replace(mod, frames=[mod.frames[i] for i in keep], images=mod.images[keep], clean=cut(mod.clean),
                   shadowed=cut(mod.shadowed), masks=cut(mod.masks), depth=cut(mod.depth),
                   inverse_depth=cut(mod.inverse_depth))
