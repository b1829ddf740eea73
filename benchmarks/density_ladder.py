"""Choosing a density ladder before rendering it: the smoky input's PSNR at density scales k,
estimated from a scene's dataset at k = 1 (``eval.density_sweep.frame_at_scale``: the smoke's
opacity 1 − (1 − α)^k over each pixel, its colour held at the k = 1 value), on the test views.

    python benchmarks/density_ladder.py DATASET... [--k 1 2 4 8 16 32 64]

Prints one row per dataset: the RGB smoke's mean optical depth −ln(1 − ᾱ) at k = 1 and the
estimated input PSNR at each k. The estimate ignores how the smoke's colour changes with its
density, so the rendered input lands near it, not on it (house at k = 64: 18.2 estimated).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from contracts.metrics import psnr
from eval.density_sweep import frame_at_scale, mean_optical_depth, frames_of_test_views


def ladder_row(root: Path, ks: list[float]) -> dict[str, float]:
    """The scene's optical depth at k = 1 and its estimated input PSNR (mean over test views) at each k."""
    views = list(frames_of_test_views(root))
    scores = {f"k{k:g}": float(np.mean([psnr(frame_at_scale(smoky, clean, alpha, k), clean)
                                         for smoky, clean, alpha in views])) for k in ks}
    return {"optical_depth_k1": mean_optical_depth([alpha for _, _, alpha in views]), **scores}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--k", nargs="+", type=float, default=[1, 2, 4, 8, 16, 32, 64])
    args = ap.parse_args()
    print("| dataset | optical depth at k = 1 | " + " | ".join(f"input at k = {k:g}" for k in args.k) + " |")
    print("|---|---|" + "---|" * len(args.k))
    for root in args.datasets:
        row = ladder_row(root, args.k)
        print(f"| {root.name} | {row['optical_depth_k1']:.3f} | "
              + " | ".join(f"{row[f'k{k:g}']:.1f}" for k in args.k) + " |")


if __name__ == "__main__":
    main()
