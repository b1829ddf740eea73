"""The density sweep's arithmetic: how much smoke a scene's test views hold, Full's lead over
RGB-only per seed, and the optical depth at which that lead turns positive.

The sweep renders one bake per scene at smoke density scales k; a pixel's opacity is then
1 − (1 − α)^k, i.e. its optical depth τ = −ln(1 − α) scales by k. Its x axis is the mean optical
depth −ln(1 − ᾱ) of the RGB smoke over the test views' pixels.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def mean_optical_depth(alphas: list[np.ndarray]) -> float:
    """−ln(1 − ᾱ), ᾱ the mean RGB smoke opacity over every pixel of the given views."""
    if not alphas:
        raise ValueError("mean_optical_depth: no views")
    mean = float(np.mean([float(np.mean(np.clip(a, 0.0, 1.0))) for a in alphas]))
    return -math.log1p(-min(mean, 1.0 - 1e-12))


@dataclass(frozen=True)
class Lead:
    """Full − RGB-only over the seeds both finished: mean and sample std of the per-seed
    differences (std None with one seed)."""

    mean: float
    std: float | None
    seeds: tuple[int, ...]


def paired_lead(full: dict[int, float], rgb_only: dict[int, float]) -> Lead | None:
    """The lead on the seeds both methods finished; None when they share none."""
    seeds = tuple(sorted(set(full) & set(rgb_only)))
    if not seeds:
        return None
    diffs = [full[s] - rgb_only[s] for s in seeds]
    mean = sum(diffs) / len(diffs)
    std = math.sqrt(sum((d - mean) ** 2 for d in diffs) / (len(diffs) - 1)) if len(diffs) > 1 else None
    return Lead(mean, std, seeds)


def crossover(depths: list[float], leads: list[float]) -> tuple[float | None, str]:
    """The optical depth at which the lead first turns from negative to non-negative, linearly
    interpolated between the two measured densities around it, and how it was found:
    "crossing", "ahead throughout" (never negative: None), "behind throughout" (never
    non-negative: None), "falls behind" (ahead at thin smoke, behind at dense: None) or
    "crossing, then behind again" when it falls back below zero later (the first crossing is
    returned)."""
    if len(depths) != len(leads) or not depths:
        raise ValueError("crossover: need one lead per optical depth, at least one")
    order = sorted(range(len(depths)), key=lambda i: depths[i])
    x = [depths[i] for i in order]
    y = [leads[i] for i in order]
    if all(v >= 0 for v in y):
        return None, "ahead throughout"
    if all(v < 0 for v in y):
        return None, "behind throughout"
    first = next((i for i in range(1, len(y)) if y[i - 1] < 0 <= y[i]), None)
    if first is None:
        return None, "falls behind"
    x0, x1, y0, y1 = x[first - 1], x[first], y[first - 1], y[first]
    at = x0 + (x1 - x0) * (-y0) / (y1 - y0)
    again = any(v < 0 for v in y[first:])
    return at, "crossing, then behind again" if again else "crossing"
