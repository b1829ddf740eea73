"""Is there smoke in a capture? Decided from the multi-view consistency of the posed RGB frames.

A static, smoke-free scene is consistent across views: for every pixel some depth maps it to
the same colour in the neighbouring frames. Smoke moves on its own and lies in front of the
surface, half transparent, so no single depth explains both layers. The test is a plane sweep
that needs no depth and no weights, only the Stage 1 poses:

- every RGB frame is compared with its ``neighbours`` nearest training frames in time (held-out
  frames are never a neighbour);
- for each fronto-parallel plane (uniform in inverse depth, from a near plane to infinity, so
  finely that adjacent planes move the image by at most ``step_px``), the frame's pixels are
  reprojected into each neighbour, and the colour difference is taken after a Gaussian blur of
  ``blur_px`` (texture finer than the blur aliases between low-resolution views; smoke is
  low-frequency);
- the median over the neighbours (robust to occlusions and to smoke in one of them), then the
  minimum over the planes, is the pixel's residual: what no depth can explain.

The statistic is the median over the frames of each frame's median residual, divided by what a
smoke-free scene leaves: a resampling floor plus the image noise's share. Noise of standard
deviation σ (estimated from the frames with Immerkær's kernel and a median, robust to edges),
blurred by a Gaussian of ``blur_px`` and differenced between two frames, has a mean absolute
value of σ / (π · blur_px). Without that division a noisy smoke-free capture and a clean smoky
one look alike (the generator denoises only frames with smoke).

Image statistics cannot do this: the temporal variance the mask estimator uses is normalised
by its own maximum, so it marks pixels in every scene (62 % of a smoke-free one), and a moving
camera changes every pixel anyway; the dark channel of the generator's bright, unsaturated
renders is higher in the smoke-free demo than in the smoky one.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import convolve, gaussian_filter, map_coordinates

from scenes.cameras import camera_center, scene_bounds
from scenes.images import box_downscale
from scenes.scene import Frame


ESTIMATOR = "multiview-residual"


@dataclass(frozen=True)
class PresenceConfig:
    """The plane sweep's settings and the decision's calibration."""

    neighbours: int = 4
    blur_px: float = 1.0
    near: float = 0.25
    """Nearest plane, as a fraction of the mean distance from the cameras to their look-at point;
    the farthest is at infinity."""
    step_px: float = 0.5
    """Largest image shift between adjacent planes, in the widest-baseline neighbour."""
    max_depths: int = 600
    aliasing_floor: float = 0.0015
    """Residual (sRGB, [0, 1]) of a noise-free smoke-free scene: resampling and occlusion edges.
    Measured on the splatted smoke-free test scene (``tests.test_smokeseer_data``), 0.0015."""
    threshold: float = 1.36
    """Residual over its expected smoke-free floor above which smoke is present. Measured on
    generated scenes with and without their smoke sources and on the splatted test scenes, with
    frames 48-96 px wide (docs/real-captures.md): smoke-free 0.57-1.21, smoky 1.54-5.0; the
    geometric mean of 1.21 and 1.54, a margin of x1.13 either way."""
    min_width: int = 48
    """Narrower frames are decided on, but the log says the threshold was not measured there."""
    max_width: int = 96
    """Frames wider than this are box-downscaled first: the size the threshold was measured at,
    and a bounded cost."""


@dataclass
class PresenceDecision:
    """The decision, the numbers behind it (for the log), and the masks it implies."""

    present: bool
    statistic: float
    threshold: float
    median_residual: float
    noise_sigma: float
    residual: np.ndarray
    """Per frame and pixel, at the working size (NaN where fewer than 2 neighbours see it)."""
    masks: np.ndarray
    """Residual above the smoke-free floor, per frame at the frames' size (0/1)."""
    notes: list[str]


def _blur(img: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return img
    return np.stack([gaussian_filter(img[..., c], sigma, mode="nearest") for c in range(img.shape[-1])], -1)


def _sample(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup at pixel coordinates whose centres sit at +0.5."""
    return np.stack([map_coordinates(img[..., c], [v - 0.5, u - 0.5], order=1, mode="nearest")
                     for c in range(img.shape[-1])], -1)


def _neighbours(frames: list[Frame], pool: list[int], k: int) -> list[list[int]]:
    """For every frame, the ``k`` frames of ``pool`` (itself excluded) nearest in time."""
    return [sorted((j for j in pool if j != i), key=lambda j: (abs(frames[j].timestamp_s - f.timestamp_s), j))[:k]
            for i, f in enumerate(frames)]


def multiview_residual(images: np.ndarray, frames: list[Frame], pool: list[int],
                       cfg: PresenceConfig = PresenceConfig()) -> np.ndarray:
    """Per-pixel colour residual that no single depth explains, for every frame, against its
    neighbours from ``pool`` (N×H×W, NaN where fewer than 2 neighbours see a pixel)."""
    if len(pool) < 3:
        raise ValueError(f"smoke presence: needs at least 3 RGB training frames, got {len(pool)}")
    bounds = scene_bounds(np.stack([frames[i].viewmat for i in pool]), np.stack([frames[i].K for i in pool]),
                          np.array([frames[i].width for i in pool]))
    centres = np.stack([camera_center(f.viewmat) for f in frames])
    near_depth = cfg.near * float(np.linalg.norm(centres[pool] - bounds.center, axis=1).mean())
    neighbours = _neighbours(frames, pool, cfg.neighbours)
    baseline = max(float(np.linalg.norm(centres[i] - centres[j])) for i, nb in enumerate(neighbours) for j in nb)
    focal = max(float(f.K[0, 0]) for f in frames)
    n = int(np.clip(np.ceil(focal * baseline / near_depth / cfg.step_px), 8, cfg.max_depths))
    inverse = np.linspace(1.0 / near_depth, 0.0, n)
    blurred = [_blur(np.asarray(im, dtype=np.float64), cfg.blur_px) for im in images]
    out = []
    for f, near, image in zip(frames, neighbours, blurred):
        v, u = np.mgrid[0:f.height, 0:f.width] + 0.5
        rays = np.stack([(u - f.K[0, 2]) / f.K[0, 0], (v - f.K[1, 2]) / f.K[1, 1], np.ones_like(u)], -1)
        best = np.full((f.height, f.width), np.inf)
        # Per neighbour, the rays turned into its frame and the baseline: the same for every plane.
        moves = []
        for j in near:
            g = frames[j]
            rot = g.viewmat[:3, :3] @ f.viewmat[:3, :3].T
            moves.append((g, blurred[j], rays @ rot.T, g.viewmat[:3, 3] - rot @ f.viewmat[:3, 3]))
        for q in inverse:
            diffs = []
            for g, neighbour_image, turned, shift in moves:
                x = turned + q * shift
                z = np.where(x[..., 2] > 1e-9, x[..., 2], np.nan)
                uj, vj = g.K[0, 0] * x[..., 0] / z + g.K[0, 2], g.K[1, 1] * x[..., 1] / z + g.K[1, 2]
                seen = np.isfinite(z) & (uj >= 0) & (uj <= g.width) & (vj >= 0) & (vj <= g.height)
                uj, vj = np.where(seen, uj, 0.0), np.where(seen, vj, 0.0)
                diff = np.abs(_sample(neighbour_image, uj, vj) - image).mean(-1)
                diffs.append(np.where(seen, diff, np.nan))
            stack = np.stack(diffs)
            enough = np.isfinite(stack).sum(0) >= 2
            med = np.nanmedian(np.where(enough[None], stack, 0.0), axis=0)
            best = np.minimum(best, np.where(enough, med, np.inf))
        out.append(np.where(np.isfinite(best), best, np.nan))
    return np.stack(out)


def noise_sigma(images: np.ndarray) -> float:
    """Per-pixel noise standard deviation of the grey frames (median over frames): Immerkær's
    kernel cancels linear image structure, and the median of its response (MAD) ignores edges."""
    kernel = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])
    grey = np.asarray(images, dtype=np.float64).mean(-1)
    return float(np.median([np.median(np.abs(convolve(g, kernel)[1:-1, 1:-1])) / (6.0 * 0.6745) for g in grey]))


def _working_size(images: np.ndarray, frames: list[Frame], factor: int) -> tuple[np.ndarray, list[Frame]]:
    if factor == 1:
        return np.asarray(images), frames
    small = np.stack([box_downscale(np.asarray(im, dtype=np.float64), factor) for im in images])
    scaled = []
    for f in frames:
        k = f.K.copy()
        k[:2] /= factor
        scaled.append(replace(f, K=k, width=small.shape[2], height=small.shape[1]))
    return small, scaled


def _upsample(masks: np.ndarray, factor: int, height: int, width: int) -> np.ndarray:
    """Nearest upsampling back to the frames' size; the rows and columns the box downscale
    cropped repeat the last ones."""
    big = masks.repeat(factor, axis=1).repeat(factor, axis=2)
    return np.pad(big, ((0, 0), (0, height - big.shape[1]), (0, width - big.shape[2])), mode="edge")


def decide_smoke_presence(images: np.ndarray, frames: list[Frame], train: list[int],
                          cfg: PresenceConfig = PresenceConfig()) -> PresenceDecision:
    """Smoke is present when the median over the training frames of each frame's median
    residual exceeds ``cfg.threshold`` times the smoke-free floor. Masks, for every frame, are
    the pixels whose residual exceeds that floor."""
    if cfg.blur_px <= 0:
        raise ValueError(f"smoke presence: blur_px must be > 0, got {cfg.blur_px}")
    height, width = frames[0].height, frames[0].width
    factor = max(1, -(-width // cfg.max_width))
    images, frames = _working_size(images, frames, factor)
    residual = multiview_residual(images, frames, train, cfg)
    per_frame = [float(np.median(r[np.isfinite(r)])) for r in residual[train] if np.isfinite(r).any()]
    if not per_frame:
        raise ValueError("smoke presence: no pixel is seen by two neighbouring frames; the poses share no view")
    median = float(np.median(per_frame))
    sigma = noise_sigma(images[train])
    floor = cfg.aliasing_floor + sigma / (np.pi * cfg.blur_px)
    stat = median / floor
    notes = [] if frames[0].width >= cfg.min_width else [
        f"smoke presence decided on frames {frames[0].width} px wide; its threshold was measured at "
        f"{cfg.min_width}-{cfg.max_width} px, so the decision is unreliable"]
    masks = _upsample((np.nan_to_num(residual, nan=0.0) > floor).astype(np.float32), factor, height, width)
    return PresenceDecision(stat > cfg.threshold, stat, cfg.threshold, median, sigma, residual, masks, notes)
