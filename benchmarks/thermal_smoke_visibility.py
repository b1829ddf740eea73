"""How much of each dataset's smoke the thermal camera sees.

    python benchmarks/thermal_smoke_visibility.py [--datasets data/standard] [--out CSV]

For every thermal frame of each dataset: the mean absolute difference between the smoky and the
clean thermal frame, over the clean frame's 0.5-99.5 percentile range (the spread the trainer's
linear thermal curve maps to [0, 1]). Near 0 the thermal frames are the clean surface, so any
cost of the thermal render loss on such a scene comes from the trainer's thermal model, not from
smoke in the long-wave infrared. Ground truth is read here for diagnosis only; no trainer reads it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from contracts.atomic import write_rows_csv
from contracts.imageio import read_png


def visibility(dataset: Path) -> dict[str, object]:
    smoky_dir, clean_dir = dataset / "thermal" / "smoky", dataset / "thermal" / "clean"
    names = sorted(p.name for p in smoky_dir.glob("*.png"))
    if not names:
        raise SystemExit(f"{smoky_dir}: no thermal frames")
    diffs, spans = [], []
    for name in names:
        smoky = read_png(smoky_dir / name).astype(np.float64)
        clean = read_png(clean_dir / name).astype(np.float64)
        diffs.append(np.abs(smoky - clean).mean())
        spans.append(np.percentile(clean, 99.5) - np.percentile(clean, 0.5))
    share = np.array(diffs) / np.maximum(np.array(spans), 1e-12)
    return {"scene": dataset.name, "frames": len(names), "mean_share": round(float(share.mean()), 5),
            "max_share": round(float(share.max()), 5)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--datasets", type=Path, default=Path("data/standard"))
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "thermal_smoke_visibility.csv")
    args = ap.parse_args(argv)
    rows = [visibility(d) for d in sorted(p.parent for p in args.datasets.glob("*/dataset.json"))]
    write_rows_csv(args.out, rows)
    for r in rows:
        print(f"{r['scene']:<11} {r['frames']:>3} frames: mean |smoky - clean| / range {r['mean_share']:.4f} "
              f"(max {r['max_share']:.4f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
