"""Raw thermal values to the [0, 1] the trainer sees: one monotone curve per dataset.

One curve for every frame of a dataset (never one per frame), so a surface keeps one thermal
value across frames, as a camera with a frozen gain curve records it. Two curves:

- ``linear``: the 0.5th and 99.5th percentiles of all frames map to 0 and 1, clipped outside.
  The percentiles keep one small hot object (a heater, a fire) from setting the top of the
  range (measured on the bench brick_toy: 90 % of pixels within 0.06 of each other under
  min/max).
- ``equalised``: plateau histogram equalisation (or, with ``equalised_share`` below 1, that
  share of it mixed with the linear curve), the contrast curve of thermal cameras' AGC:
  the cumulative histogram of every pixel of the dataset, each bin clipped at ``PLATEAU`` times
  the mean bin count so that a large uniform wall does not take the whole range. Why: when a
  warm object covers more than the top half-percent (the standard food_plate's grill), the
  linear range still puts 92 % of the pixels in one 0.06-wide window (room 80 %, forest 82 %),
  where the photometric loss barely sees geometry. Fully equalised, warm smoke can become one
  of the brightest things in view (forest), which Stage 2 fits as surface; the standard
  profile mixes the two half and half (docs/method.md "Data").

``invert`` maps trained values back to raw units for the thermal renders.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

THERMAL_SCALES: tuple[str, ...] = ("linear", "equalised")
LINEAR_PERCENTILES = (0.5, 99.5)
EQUALISE_BINS = 2048
PLATEAU = 4.0
CROWDING_WIDTH = 0.06  # the ``crowded`` statistic: share of pixels in the fullest window this wide


@dataclass(frozen=True)
class ThermalScale:
    """A monotone piecewise-linear curve: raw ``knots`` (increasing) to ``levels`` in [0, 1]
    (non-decreasing); constant beyond the ends."""

    kind: str
    knots: np.ndarray
    levels: np.ndarray
    equalised_share: float = 0.0

    def apply(self, raw: np.ndarray) -> np.ndarray:
        return np.interp(raw, self.knots, self.levels).astype(np.float32)

    def invert(self, level: np.ndarray) -> np.ndarray:
        """Raw values for trained ones, clamped to the curve's ends; a level on a flat stretch of
        the curve (empty histogram bins) gives the stretch's highest raw value."""
        y = np.clip(np.asarray(level, dtype=np.float64), self.levels[0], self.levels[-1])
        j = np.clip(np.searchsorted(self.levels, y, side="right") - 1, 0, len(self.levels) - 2)
        below, above = self.levels[j], self.levels[j + 1]
        rise = above - below
        frac = np.where(rise > 0, (y - below) / np.where(rise > 0, rise, 1.0), 0.0)
        return self.knots[j] + frac * (self.knots[j + 1] - self.knots[j])

    @property
    def raw_range(self) -> tuple[float, float]:
        """The raw values mapped to 0 and 1."""
        return float(self.knots[0]), float(self.knots[-1])

    def record(self, mapped: np.ndarray) -> dict[str, Any]:
        """For metrics.json and the log: the curve's kind, its raw range, its settings, and how
        crowded the mapped training values are (share of pixels in the fullest 0.06 window)."""
        doc: dict[str, Any] = {"kind": self.kind, "raw_range": list(self.raw_range),
                               "crowded": round(crowded_fraction(mapped), 4)}
        if self.kind == "equalised":
            doc.update({"bins": EQUALISE_BINS, "plateau": PLATEAU, "equalised_share": self.equalised_share})
        if self.kind == "linear" or self.equalised_share < 1.0:
            doc["percentiles"] = list(LINEAR_PERCENTILES)
        return doc

    def describe(self, crowded: float) -> str:
        """One log line; ``crowded`` as in ``record``."""
        lo, hi = self.raw_range
        share = f" (share {self.equalised_share:g}, the rest linear)" if 0 < self.equalised_share < 1 else ""
        return (f"{self.kind}{share} over raw {lo:.6g}..{hi:.6g}; {100 * crowded:.0f} % of pixels "
                f"within {CROWDING_WIDTH} of each other")


@dataclass(frozen=True)
class ThermalScaleSpec:
    """Which curve a loader fits (``TrainConfig.thermal_scale`` and ``thermal_equalised_share``)."""

    kind: str = "linear"
    equalised_share: float = 1.0

    def fit(self, stack: np.ndarray) -> ThermalScale:
        return fit_thermal_scale(stack, self.kind, self.equalised_share)


LINEAR_SCALE = ThermalScaleSpec()


def check_thermal_scale(kind: str, equalised_share: float) -> None:
    """Reject a curve that cannot be fitted, naming the config field."""
    if kind not in THERMAL_SCALES:
        raise ValueError(f"thermal_scale: {kind!r} is not one of {', '.join(THERMAL_SCALES)}")
    if not 0.0 < equalised_share <= 1.0:
        raise ValueError(f"thermal_equalised_share: must be in (0, 1], got {equalised_share}")


def fit_thermal_scale(stack: np.ndarray, kind: str, equalised_share: float = 1.0) -> ThermalScale:
    """The dataset's curve from every raw thermal value of every frame. ``equalised_share`` < 1
    mixes the equalised curve with the linear one (that share equalised, the rest linear). A
    constant stack (no contrast to spread) gets a unit-wide ramp from its value, so values stay
    finite."""
    check_thermal_scale(kind, equalised_share)
    values = np.asarray(stack, dtype=np.float64)
    low, high = float(values.min()), float(values.max())
    share = equalised_share if kind == "equalised" else 0.0
    if high - low < 1e-9:
        return ThermalScale(kind, np.array([low, low + 1.0]), np.array([0.0, 1.0]), share)
    lo, hi = (float(v) for v in np.percentile(values, LINEAR_PERCENTILES))
    if hi - lo < 1e-9:
        lo, hi = low, high
    if kind == "linear":
        return ThermalScale("linear", np.array([lo, hi]), np.array([0.0, 1.0]))
    hist, edges = np.histogram(values, bins=EQUALISE_BINS, range=(low, high))
    clipped = np.minimum(hist, PLATEAU * hist.sum() / EQUALISE_BINS)
    levels = np.concatenate([[0.0], np.cumsum(clipped) / clipped.sum()])
    if share == 1.0:
        return ThermalScale("equalised", edges, levels, share)
    knots = np.union1d(edges, [lo, hi])
    mixed = share * np.interp(knots, edges, levels) + (1.0 - share) * np.interp(knots, [lo, hi], [0.0, 1.0])
    return ThermalScale("equalised", knots, mixed, share)


def crowded_fraction(mapped: np.ndarray, width: float = CROWDING_WIDTH) -> float:
    """The largest share of values inside any window ``width`` wide (to 1/1000 of the range): near
    1 when the curve leaves the scene's contrast in a sliver of [0, 1]."""
    values = np.asarray(mapped, dtype=np.float64).ravel()
    if values.size == 0:
        return 0.0
    hist, _ = np.histogram(values, bins=1000, range=(0.0, 1.0))
    window = max(1, int(round(width * 1000)))
    return float(np.convolve(hist, np.ones(window), mode="valid").max() / values.size)
