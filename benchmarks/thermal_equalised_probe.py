"""Experiment (the loader has no such option yet): thermal frames mapped to [0, 1] by plateau histogram
equalisation over the whole dataset (one monotone curve for every frame, as a camera's AGC
with a frozen curve) instead of the linear 0.5-99.5 percentile range, then the normal CLI.
Why: on food_plate 92 % of the thermal pixels lie within 0.06 of each other under the linear
range (the grill sets its top), and Stage 2 leaves 99 % of the RGB views uncovered.
The curve: a 2048-bin histogram of every thermal pixel of the dataset between its minimum and
maximum, each bin clipped at 4x the mean bin count, cumulated. Results in
benchmarks/results/standard/README.md (late session of 2026-11-24).
Usage: python benchmarks/thermal_equalised_probe.py DATASET --mode full --profile standard --out RUN ..."""
import sys

import numpy as np

import smokeseer.data as data
from smokeseer.cli import main

BINS, PLATEAU = 2048, 4.0
state = {}


def equalised(stack):
    counts = tuple(float(v) for v in np.percentile(stack, data.THERMAL_RANGE_PERCENTILES))
    lo, hi = float(stack.min()), float(stack.max())
    hist, edges = np.histogram(stack, bins=BINS, range=(lo, hi))
    clipped = np.minimum(hist, PLATEAU * hist.sum() / BINS)
    cdf = np.concatenate([[0.0], np.cumsum(clipped) / clipped.sum()])
    state["lut"] = (edges, cdf)
    return apply(stack, counts), counts


def apply(stack, counts):
    edges, cdf = state["lut"]
    return np.interp(stack, edges, cdf).astype(np.float32)


data._normalise_counts = equalised
data.normalise_with = apply
sys.exit(main(sys.argv[1:]))
