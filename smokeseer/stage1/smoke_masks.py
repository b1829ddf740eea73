"""Single-image and temporal smoke-mask candidates, needing no weights.

``stage1=estimate`` no longer uses them: its masks come from the multi-view residual of
``smokeseer.stage1.smoke_presence``, which beat them on validation views (docs/real-captures.md). They
stay as the reference candidates of ``benchmarks/smoke_masks.py``.

The paper's Stage 1 segments smoke with GroundedSAM, whose weights cannot be had offline. These
candidates need no weights; ``benchmarks/smoke_masks.py`` measures their IoU against the
synthetic ground-truth masks, picks the candidate and threshold on the validation frames
(training views, never test views), and writes the curve to ``benchmarks/results/``.

- **dark channel** (He et al. 2009): haze = 1 − transmission, where transmission comes from the
  patch minimum of the colour minimum, normalised by the brightest (atmospheric) colour. Grey
  and white smoke lifts the dark channel of whatever is behind it.
- **whiteness**: brightness × (1 − saturation); smoke is bright and colourless.
- **dark-channel deviation**: |haze − the frame's median haze|; smoke darker than the
  background (sooty smoke against a bright sky) lowers the dark channel instead of raising it.
- **colour deviation**: distance of the locally averaged colour from the frame's median colour.
- **temporal variance**: the per-pixel standard deviation over the frames; only meaningful for
  a static camera, and measured so that this is shown rather than assumed.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import minimum_filter, uniform_filter

# On the validation (training) views of the demo and the ten bench scenes (12 frames, 96x72;
# benchmarks/results/smoke_masks*.csv) the best of these, temporal variance at 0.02, reaches a
# mean IoU of 0.693 against 0.687 for the trivial mask that calls every pixel smoke (ground
# truth alpha > 0.02 covers 24-100 % of the pixels of those scenes); the multi-view residual 0.700.
CANDIDATES = ("dark-channel", "dark-channel-deviation", "whiteness", "colour-deviation", "temporal-variance")
PATCH_FRACTION = 1 / 32


def dark_channel_haze(images: np.ndarray, patch_fraction: float = PATCH_FRACTION) -> np.ndarray:
    """1 − transmission per pixel, in [0, 1], for N×H×W×3 images in [0, 1]."""
    n, h, w, _ = images.shape
    patch = max(1, int(round(patch_fraction * max(h, w))) | 1)
    darkest = images.min(axis=-1)
    dark = np.stack([minimum_filter(d, size=patch, mode="nearest") for d in darkest])
    k = max(1, int(0.001 * h * w))
    atmosphere = np.empty((n, 3))
    for i in range(n):
        top = np.argsort(dark[i].ravel())[-k:]
        atmosphere[i] = images[i].reshape(-1, 3)[top].mean(0)
    normalised = images / np.maximum(atmosphere[:, None, None, :], 1e-3)
    dark_norm = np.stack([minimum_filter(d, size=patch, mode="nearest") for d in normalised.min(axis=-1)])
    return np.clip(dark_norm, 0.0, 1.0)


def whiteness(images: np.ndarray) -> np.ndarray:
    hi = images.max(axis=-1)
    lo = images.min(axis=-1)
    saturation = np.where(hi > 1e-6, (hi - lo) / np.maximum(hi, 1e-6), 0.0)
    return hi * (1.0 - saturation)


def deviation_from_median(score: np.ndarray) -> np.ndarray:
    """|score − its per-frame median|, in the score's own units (so one threshold means the same
    thing in every frame and every scene)."""
    return np.clip(np.abs(score - np.median(score, axis=(1, 2), keepdims=True)), 0.0, 1.0)


def colour_deviation(images: np.ndarray, patch_fraction: float = PATCH_FRACTION) -> np.ndarray:
    n, h, w, _ = images.shape
    size = max(1, int(round(patch_fraction * max(h, w))) | 1)
    median = np.median(images.reshape(n, -1, 3), axis=1)[:, None, None, :]
    dist = np.linalg.norm(images - median, axis=-1)
    return deviation_from_median(np.stack([uniform_filter(d, size=size, mode="nearest") for d in dist]))


def temporal_variance(images: np.ndarray) -> np.ndarray:
    grey = images.mean(axis=-1)
    std = grey.std(axis=0, keepdims=True)
    return np.repeat(np.clip(std / max(float(std.max()), 1e-6), 0.0, 1.0), len(images), axis=0)


def candidate_scores(images: np.ndarray, estimator: str) -> np.ndarray:
    """Per-pixel smoke score in [0, 1] (N×H×W) of one candidate."""
    if estimator == "dark-channel":
        return dark_channel_haze(images)
    if estimator == "dark-channel-deviation":
        return deviation_from_median(dark_channel_haze(images))
    if estimator == "colour-deviation":
        return colour_deviation(images)
    if estimator == "whiteness":
        return whiteness(images)
    if estimator == "temporal-variance":
        return temporal_variance(images)
    raise ValueError(f"estimator: {estimator!r} is not one of {', '.join(CANDIDATES)}")


def iou(pred: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two binary masks; 1 when both are empty."""
    p, t = np.asarray(pred) > 0.5, np.asarray(truth) > 0.5
    union = np.logical_or(p, t).sum()
    return float(np.logical_and(p, t).sum() / union) if union else 1.0
