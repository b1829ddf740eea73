"""Whether the training input can teach what the method needs, read off the frames and poses
before training: each check measures one statistic, and a value past its limit becomes a warning
(log and metrics.json ``warnings``) with the value beside it.

- ``rgb-saturated``: the share of training RGB values clipped at 0 or 1 (8-bit ends). At least
  ``MAX_CLIPPED_SHARE``: what lies there is lost to training and to scoring.
- ``rgb-constant`` / ``thermal-flat``: the frames' contrast, the median over training frames of
  the spread of a frame's values (0.5th to 99.5th percentile) over its noise (a robust σ from
  neighbouring pixels, 1.4826 × the median absolute horizontal difference / √2) plus one 8-bit
  level. Noise alone gives about 5 (the spread of a Gaussian's 99 % is 5.2 σ); a constant frame 0.
  Under ``MIN_CONTRAST`` the frames carry nothing to fit. Flat thermal frames teach Stage 2 no
  geometry, so a method that would use them trains without them, as RGB-only does
  (``smokeseer.train.plan``).
- ``no-parallax``: per modality, the diameter of the training camera centres over their mean
  distance to the scene centre (Stage 1's bounds); the smallest is recorded. Under
  ``MIN_PARALLAX`` depth cannot be triangulated from that modality's frames.

Calibration, on the ten standard datasets, the density sweep's densest (k8) and the demo, at the
quick profile's width and at full size: clipped share at most 0.086 (food_plate); RGB contrast
at least 23 (median over frames; 15.5 for the single lowest frame); thermal contrast at least 43
(29); parallax at least 0.58 (demo). Each limit sits several times from those values and from
the degenerate case it is for.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.distance import pdist

from contracts.results_format import RunWarning
from scenes.cameras import SceneBounds, camera_center
from scenes.scene import ModalityData, SceneData

MAX_CLIPPED_SHARE = 0.5
"""Share of RGB values at 0 or 1 from which ``rgb-saturated`` warns (the bench's black-sky test
scene has 0.34 at 0; the standard datasets at most 0.086)."""
MIN_CONTRAST = 8.0
"""Contrast (spread over noise) under which frames count as flat: noise alone gives about 5."""
MIN_PARALLAX = 0.02
"""Camera baseline over distance to the scene under which ``no-parallax`` warns (about 1.1°)."""
LEVEL = 1.0 / 255.0
"""One 8-bit level of the trainer's [0, 1] values: the noise floor of noise-free frames."""


def clipped_share(images: np.ndarray) -> float:
    """The share of values at 0 or 1 (within half an 8-bit level)."""
    return float(((images <= 0.5 * LEVEL) | (images >= 1.0 - 0.5 * LEVEL)).mean())


def frame_contrast(frame: np.ndarray) -> float:
    """One (H, W) frame's spread (0.5th to 99.5th percentile) over its noise plus one 8-bit level."""
    lo, hi = np.percentile(frame, (0.5, 99.5))
    noise = 1.4826 * float(np.median(np.abs(np.diff(frame, axis=1)))) / np.sqrt(2.0)
    return float(hi - lo) / (noise + LEVEL)


def contrast(images: np.ndarray) -> float:
    """The median ``frame_contrast`` of (N, H, W, C) frames in [0, 1], channels averaged."""
    return float(np.median([frame_contrast(f.mean(-1)) for f in images]))


def parallax(mod: ModalityData, bounds: SceneBounds) -> float:
    """One modality's training cameras: their diameter over their mean distance to the scene centre."""
    centres = np.stack([camera_center(v) for v in mod.cameras("train")[0]])
    diameter = float(pdist(centres).max()) if len(centres) > 1 else 0.0
    distance = float(np.linalg.norm(centres - bounds.center, axis=1).mean())
    return diameter / distance if distance > 0 else 0.0


def thermal_flat(scene: SceneData) -> RunWarning | None:
    """``thermal-flat`` when the training thermal frames carry no contrast; None when they do or
    there are none."""
    if scene.thermal is None:
        return None
    value = contrast(scene.thermal.images[scene.thermal.indices("train")])
    if value >= MIN_CONTRAST:
        return None
    return RunWarning("thermal-flat", f"the thermal frames carry no contrast (spread {value:.3g} × their noise, "
                        f"under {MIN_CONTRAST:g}), so this run trains without thermal, as RGB-only does",
                        "contrast", value, MIN_CONTRAST)


def input_warnings(scene: SceneData, bounds: SceneBounds) -> list[RunWarning]:
    """The RGB and camera checks (the thermal one decides the plan: ``thermal_flat``)."""
    rgb = scene.rgb.images[scene.rgb.indices("train")]
    found = []
    share = clipped_share(rgb)
    if share >= MAX_CLIPPED_SHARE:
        found.append(RunWarning("rgb-saturated", f"{100 * share:.0f} % of the training RGB values are clipped at 0 or "
                                  f"1 (warned from {100 * MAX_CLIPPED_SHARE:.0f} %): what lies there is lost to training "
                                  "and to scoring", "clipped_share", share, MAX_CLIPPED_SHARE))
    level = contrast(rgb)
    if level < MIN_CONTRAST:
        found.append(RunWarning("rgb-constant", f"the training RGB frames carry no contrast (spread {level:.3g} × "
                                  f"their noise, under {MIN_CONTRAST:g}): there is no scene in them to fit",
                                  "contrast", level, MIN_CONTRAST))
    mods = [scene.rgb] + ([scene.thermal] if scene.thermal is not None else [])
    spreads = {m.name: parallax(m, bounds) for m in mods}
    flat = [name for name, v in spreads.items() if v < MIN_PARALLAX]
    if flat:
        least = min(spreads.values())
        found.append(RunWarning("no-parallax", f"the training {' and '.join(flat)} cameras lie within "
                                  f"{100 * least:.3g} % of their distance to the scene of one another (warned under "
                                  f"{100 * MIN_PARALLAX:g} %): depth cannot be triangulated, so the geometry is a guess",
                                  "parallax", least, MIN_PARALLAX))
    return found
