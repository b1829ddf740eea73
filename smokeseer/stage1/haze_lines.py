"""The smoke's colour read off the smoky frames ("haze lines"), for Stage 3 under dense smoke.

Through smoke of colour k and transmittance T a surface of colour s shows I = k + T (s - k). As
the smoke moves, the frames that see one surface point give colours on a line through k, and
the lines of many points meet at k. The surface geometry (Stage 2's, rendered as depth at the RGB
cameras) says which pixels of which frames see the same point; k is the least-squares meeting
point of the lines. This matters because under dense smoke the images alone let Stage 3 trade a
brighter, denser smoke against a darker surface (docs/method.md, "Smoke colour").

How far the estimate is trusted is a number in [0, 1] (``trust``), not a yes or no: it grows
with the number of lines, the share of them that meet, and how dark the colour is (an absorbing
smoke adds little light of its own; a scattering one's radiance follows the light and the view).
Each factor rises linearly between two settings, so two runs whose estimates differ a little
train a little differently, never across a step. Two trusts are read off one estimate, differing
only in where the darkness factor reaches 1: the colour's, which Stage 3 blends with each smoke
Gaussian's own, and the surface start's (``surface_trust``), which decides how far the RGB Stage 2
is believed. A colour partly learned where it was right costs little; an RGB start under dense
smoke costs much, so the colour's ramp reaches full trust only at a darker colour.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.cameras import backproject, pixels_of
from smokeseer.config import Stage3Config


@dataclass(frozen=True)
class HazeLineSettings:
    """How points are sampled and which observation lines are trusted."""

    reference_every: int = 6
    """Every n-th training frame is a reference whose pixels are back-projected."""
    points_per_reference: int = 300
    min_observations: int = 8
    depth_tolerance: float = 0.03
    """A frame sees the point when its rendered depth there is within this fraction of the point's."""
    min_linearity: float = 3.0
    """Largest over second-largest spread (standard deviation) of a point's colours."""
    min_spread: float = 0.03
    """Least standard deviation of a point's colours along its line (colours in [0, 1])."""
    min_lines: int = 100
    """Fewer lines give no estimate; the trust's line factor rises from 0 here ..."""
    full_lines: int = 400
    """... to 1 here."""
    meet_tolerance: float = 0.03
    min_meeting_fraction: float = Stage3Config.smoke_color_min_meeting
    """The fraction of lines passing within ``meet_tolerance`` of the estimate where the meeting
    factor leaves 0 ..."""
    full_meeting_fraction: float = Stage3Config.smoke_color_full_meeting
    """... and where it reaches 1."""
    max_brightness: float = Stage3Config.smoke_color_max_brightness
    """The channel mean where the brightness factor reaches 0 (why: ``Stage3Config``) ..."""
    full_brightness: float = Stage3Config.smoke_color_full_brightness
    """... and the darker one where the colour's trust is 1 ..."""
    surface_full_brightness: float = Stage3Config.surface_full_brightness
    """... and the one where the surface start's is (``surface_trust``)."""

    @classmethod
    def of(cls, stage3: Stage3Config) -> "HazeLineSettings":
        """The settings a run's Stage 3 uses (its meeting and brightness ramps)."""
        return cls(min_meeting_fraction=stage3.smoke_color_min_meeting,
                   full_meeting_fraction=stage3.smoke_color_full_meeting,
                   max_brightness=stage3.smoke_color_max_brightness,
                   full_brightness=stage3.smoke_color_full_brightness,
                   surface_full_brightness=stage3.surface_full_brightness)


@dataclass
class SmokeColourEstimate:
    """The meeting point and how far it is trusted, or None with the reason there is none."""

    colour: np.ndarray | None
    """The point nearest to all lines, inside the colour cube; None: no estimate (``reason``)."""
    lines: int
    points: int
    meeting_fraction: float | None = None
    reason: str = ""
    """Why there is no estimate, or what keeps its trust under 1 ("" at full trust)."""
    meeting: np.ndarray | None = None
    """``colour`` when at least ``min_meeting_fraction`` of the lines meet, trusted or not: a bright
    smoke's colour too view-dependent to hold still places its density (``loss.mask_floor_where``)."""
    trust: float = 0.0
    """In [0, 1]: each smoke Gaussian shows trust × ``colour`` + (1 − trust) × its own (``trust``)."""
    surface_trust: float = 0.0
    """In [0, 1], at least ``trust``: the RGB Stage 2 keeps 1 − this of its opacities in Stage 3's
    start (``smokeseer.train.surface_union.surface_start``)."""
    meeting_weight: float = 0.0
    """In [0, 1]: how far ``colour`` is trusted to place the smoke's density, the trust's line and
    meeting ramps without its darkness one (``loss.mask_floor_meeting=trusted``)."""

    def describe(self) -> str:
        met = "" if self.meeting_fraction is None else f", {self.meeting_fraction:.2f} of them meeting"
        if self.colour is None:
            found = f"none: {self.reason}"
        else:
            found = (f"{np.round(self.colour, 3).tolist()}, trust {self.trust:.3f}, surface trust {self.surface_trust:.3f}"
                     + (f" ({self.reason})" if self.reason else ""))
        return f"{found} ({self.lines} observation lines from {self.points} points{met})"


def ramp(value: float, zero: float, one: float) -> float:
    """0 at ``zero``, 1 at ``one``, linear between and flat outside (either direction)."""
    return float(np.clip((value - zero) / (one - zero), 0.0, 1.0))


def meeting_factors(lines: int, met: float, settings: HazeLineSettings) -> dict[str, float]:
    """The ramps of enough lines and of lines that meet, by what each reads."""
    return {f"{lines} lines (full at {settings.full_lines})": ramp(lines, settings.min_lines, settings.full_lines),
            f"{met:.2f} of the lines meet (full at {settings.full_meeting_fraction})":
                ramp(met, settings.min_meeting_fraction, settings.full_meeting_fraction)}


def trust(colour: np.ndarray, lines: int, met: float, settings: HazeLineSettings,
          full_brightness: float) -> tuple[float, str]:
    """The product of three ramps, enough lines, lines that meet and a dark colour (1 at channel
    mean ``full_brightness`` or under), and what holds it under 1 ("" at 1)."""
    mean = float(np.mean(colour))
    factors = {
        **meeting_factors(lines, met, settings),
        f"channel mean {mean:.2f} (full at {full_brightness} or darker: a scattering smoke's radiance follows "
        "the light and the view)": ramp(mean, settings.max_brightness, full_brightness)}
    value = float(np.prod(list(factors.values())))
    return value, "; ".join(f"{why}: {f:.2f}" for why, f in factors.items() if f < 1.0)


def in_cube(colour: np.ndarray) -> bool:
    return not (np.any(colour < -0.05) or np.any(colour > 1.05))


def observations(points: np.ndarray, images: np.ndarray, depths: np.ndarray, valid: np.ndarray,
                 viewmats: np.ndarray, Ks: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's colour of each world point (frames, points, 3) and whether the frame sees it:
    in front of the camera, inside the image, and not hidden (rendered depth agrees)."""
    n_frames, height, width = depths.shape
    colours = np.zeros((n_frames, len(points), images.shape[-1]), dtype=np.float64)
    seen = np.zeros((n_frames, len(points)), dtype=bool)
    for f in range(n_frames):
        inside, iu, iv, z = pixels_of(points, viewmats[f], Ks[f], width, height)
        rendered = depths[f, iv, iu]
        ok = valid[f, iv, iu] & (np.abs(rendered - z[inside]) <= tolerance * z[inside])
        idx = np.nonzero(inside)[0][ok]
        seen[f, idx] = True
        colours[f, idx] = images[f, iv[ok], iu[ok]]
    return colours, seen


def fit_lines(colours: np.ndarray, seen: np.ndarray, settings: HazeLineSettings
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per point with enough views, the line its colours lie on: (means, unit directions,
    weights = spread along the line); points whose colours do not spread along one line are left out."""
    counts = seen.sum(0)
    keep = counts >= settings.min_observations
    w = seen[:, keep, None].astype(np.float64)
    c = colours[:, keep]
    n = counts[keep][:, None]
    means = (w * c).sum(0) / n
    centred = (c - means[None]) * w
    cov = np.einsum("fpi,fpj->pij", centred, centred) / n[:, :, None]
    eigval, eigvec = np.linalg.eigh(cov)
    spread = np.sqrt(np.clip(eigval[:, -1], 0.0, None))
    second = np.sqrt(np.clip(eigval[:, -2], 0.0, None))
    good = (spread >= settings.min_spread) & (spread >= settings.min_linearity * second)
    return means[good], eigvec[good, :, -1], spread[good]


def line_distances(point: np.ndarray, means: np.ndarray, directions: np.ndarray) -> np.ndarray:
    offset = point[None] - means
    along = (offset * directions).sum(1, keepdims=True) * directions
    return np.linalg.norm(offset - along, axis=1)


def meeting_point(means: np.ndarray, directions: np.ndarray, weights: np.ndarray) -> np.ndarray | None:
    """The point closest to all lines (weighted least squares); None when the lines are
    (nearly) parallel and so meet nowhere in particular."""
    proj = np.eye(means.shape[1])[None] - directions[:, :, None] * directions[:, None, :]
    A = (weights[:, None, None] * proj).sum(0)
    b = (weights[:, None, None] * proj @ means[:, :, None]).sum(0)[:, 0]
    eig = np.linalg.eigvalsh(A)
    if eig[0] <= 1e-3 * eig[-1]:
        return None
    return np.linalg.solve(A, b)


def estimate_smoke_colour(images: np.ndarray, depths: np.ndarray, valid: np.ndarray, viewmats: np.ndarray,
                          Ks: np.ndarray, rng: np.random.Generator,
                          settings: HazeLineSettings = HazeLineSettings()) -> SmokeColourEstimate:
    """Smoke colour from training frames ``images`` (frames, H, W, C) in [0, 1], with the surface's
    planar depth per frame (``valid`` where the geometry covers the pixel)."""
    n_frames, height, width = depths.shape
    all_means, all_dirs, all_weights, n_points = [], [], [], 0
    for ref in range(0, n_frames, settings.reference_every):
        vs = rng.integers(0, height, settings.points_per_reference)
        us = rng.integers(0, width, settings.points_per_reference)
        ok = valid[ref, vs, us]
        if not ok.any():
            continue
        pts = backproject(depths[ref, vs[ok], us[ok]], np.stack([us[ok], vs[ok]], 1), viewmats[ref], Ks[ref])
        colours, seen = observations(pts, images, depths, valid, viewmats, Ks, settings.depth_tolerance)
        means, dirs, weights = fit_lines(colours, seen, settings)
        n_points += len(pts)
        all_means.append(means)
        all_dirs.append(dirs)
        all_weights.append(weights)
    lines = int(sum(len(m) for m in all_means))
    if lines < settings.min_lines:
        return SmokeColourEstimate(None, lines, n_points, reason=f"fewer than {settings.min_lines} observation "
                                   f"lines (from {n_points} sampled points the geometry covers): too little "
                                   "geometry, or smoke that barely changes what the surface shows")
    means, dirs = np.concatenate(all_means), np.concatenate(all_dirs)
    colour = meeting_point(means, dirs, np.concatenate(all_weights))
    if colour is None:
        return SmokeColourEstimate(None, lines, n_points, reason="the observation lines are parallel")
    met = float((line_distances(colour, means, dirs) <= settings.meet_tolerance).mean())
    if not in_cube(colour):
        return SmokeColourEstimate(None, lines, n_points, met,
                                   f"the lines meet outside the colour cube, at {np.round(colour, 3).tolist()}")
    colour = np.clip(colour, 0.01, 0.99)
    value, limits = trust(colour, lines, met, settings, settings.full_brightness)
    surface, _ = trust(colour, lines, met, settings, settings.surface_full_brightness)
    meeting = colour if met >= settings.min_meeting_fraction else None
    weight = float(np.prod(list(meeting_factors(lines, met, settings).values())))
    return SmokeColourEstimate(colour, lines, n_points, met, limits, meeting, value, surface, weight)
