"""Rows of clean truth, smoky input, a run's surface and smoke renders and the surface's error,
one row per (run, test frame): where in the image a method loses to the input.

    python benchmarks/error_maps.py --out FIG.png LABEL=DATASET:RUN:STEM [...]

The error panel is the mean absolute error over channels times 4 (white = 0.25 or more); the
row title gives the frame's surface and input PSNR (8-bit images, as eval/regions.py reads them).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from contracts.imageio import image01, read_png  # noqa: E402
from eval.regions import pooled_psnr  # noqa: E402

COLUMNS = ("clean truth", "smoky input", "surface", "smoke (render)", "|surface - clean| x 4")


def _rgb(path: Path) -> np.ndarray:
    return image01(read_png(path))


def panels(dataset: Path, run: Path, stem: str) -> tuple[list[np.ndarray], float, float]:
    clean, smoky = _rgb(dataset / "rgb" / "clean" / f"{stem}.png"), _rgb(dataset / "rgb" / "smoky" / f"{stem}.png")
    surface = _rgb(run / "renders" / "surface" / f"{stem}.png")
    smoke = _rgb(run / "renders" / "smoke" / f"{stem}.png")
    error = np.clip(np.abs(surface - clean).mean(-1) * 4, 0, 1)
    n = clean.size
    return ([clean, smoky, surface, smoke, error], pooled_psnr(float(((surface - clean) ** 2).sum()), n),
            pooled_psnr(float(((smoky - clean) ** 2).sum()), n))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+", help="LABEL=DATASET:RUN:STEM")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    fig, axes = plt.subplots(len(args.rows), len(COLUMNS), figsize=(2.6 * len(COLUMNS), 2.1 * len(args.rows)),
                             squeeze=False)
    for i, row in enumerate(args.rows):
        label, spec = row.split("=", 1)
        dataset, run, stem = spec.split(":")
        images, psnr, psnr_input = panels(Path(dataset), Path(run), stem)
        for j, img in enumerate(images):
            ax = axes[i][j]
            ax.imshow(img, cmap="gray" if img.ndim == 2 else None, vmin=0, vmax=1, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(COLUMNS[j], fontsize=8)
        axes[i][0].set_ylabel(f"{label}\nframe {stem}\n{psnr:.1f} dB (input {psnr_input:.1f})", fontsize=7)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
