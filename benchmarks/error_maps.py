"""Rows of clean truth, smoky input, a run's surface and smoke renders and the surface's error,
one row per (run, test frame): where in the image a method loses to the input.

    python benchmarks/error_maps.py --out FIG.png [--without-smoke] LABEL=DATASET:RUN:STEM [...]

`--without-smoke` drops the smoke column, for runs whose smoke renders were not kept (the table
runs commit the surface renders only, data/README.md). The error panel is the mean absolute
error over channels times 4 (white = 0.25 or more); the row title gives the frame's surface and
input PSNR (8-bit images, as eval/regions.py reads them).
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

from contracts.atomic import atomic_path  # noqa: E402
from contracts.imageio import image01, read_png  # noqa: E402
from eval.regions import pooled_psnr  # noqa: E402

SMOKE_COLUMN = "smoke (render)"
COLUMNS = ("clean truth", "smoky input", "surface", SMOKE_COLUMN, "|surface - clean| x 4")


def _rgb(path: Path) -> np.ndarray:
    return image01(read_png(path))


def row_files(dataset: Path, run: Path, stem: str, smoke: bool) -> list[Path]:
    """The images a row reads, in COLUMNS order up to the error panel (no smoke render unless
    `smoke`): what main checks before drawing and panels reads."""
    files = [dataset / "rgb" / "clean" / f"{stem}.png", dataset / "rgb" / "smoky" / f"{stem}.png",
             run / "renders" / "surface" / f"{stem}.png"]
    return files + ([run / "renders" / "smoke" / f"{stem}.png"] if smoke else [])


def panels(dataset: Path, run: Path, stem: str, smoke: bool) -> tuple[list[np.ndarray], float, float]:
    """The row's images in COLUMNS order (without the smoke render unless `smoke`), and the
    surface's and the input's PSNR against the clean truth."""
    images = [_rgb(p) for p in row_files(dataset, run, stem, smoke)]
    clean, smoky, surface = images[:3]
    images.append(np.clip(np.abs(surface - clean).mean(-1) * 4, 0, 1))
    n = clean.size
    return (images, pooled_psnr(float(((surface - clean) ** 2).sum()), n),
            pooled_psnr(float(((smoky - clean) ** 2).sum()), n))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+", help="LABEL=DATASET:RUN:STEM")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--without-smoke", action="store_true", help="leave out the smoke render column")
    args = ap.parse_args()
    columns = [c for c in COLUMNS if not (args.without_smoke and c == SMOKE_COLUMN)]
    rows = []
    for row in args.rows:
        label, _, spec = row.partition("=")
        parts = spec.split(":")
        if len(parts) != 3:
            sys.exit(f"error_maps.py: row {row!r}: expected LABEL=DATASET:RUN:STEM")
        dataset, run, stem = Path(parts[0]), Path(parts[1]), parts[2]
        missing = [p for p in row_files(dataset, run, stem, not args.without_smoke) if not p.is_file()]
        if missing:
            hint = " (pass --without-smoke for runs whose smoke renders were not kept)" if missing[0].parent.name == "smoke" else ""
            sys.exit(f"error_maps.py: row {label!r}: {missing[0]} not found{hint}")
        rows.append((label, dataset, run, stem))
    fig, axes = plt.subplots(len(rows), len(columns), figsize=(2.6 * len(columns), 2.1 * len(rows)), squeeze=False)
    for i, (label, dataset, run, stem) in enumerate(rows):
        images, psnr, psnr_input = panels(dataset, run, stem, smoke=not args.without_smoke)
        for j, img in enumerate(images):
            ax = axes[i][j]
            ax.imshow(img, cmap="gray" if img.ndim == 2 else None, vmin=0, vmax=1, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(columns[j], fontsize=8)
        axes[i][0].set_ylabel(f"{label}\nframe {stem}\n{psnr:.1f} dB (input {psnr_input:.1f})", fontsize=7)
    fig.tight_layout()
    with atomic_path(args.out) as partial:
        fig.savefig(partial, dpi=110, format="png")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
