"""How much of the smoky input's gap to the clean truth is the smoke's shadow: per dataset, the test
views' PSNR of the smoky input against `clean` and against `shadowed` (the scene under the smoke's
shadow with no smoke in view), and of `shadowed` against `clean`.

    python benchmarks/shadow_share.py data/standard/*/ [--out benchmarks/results/standard/shadow_share.csv]

Reads each dataset's `stats.test_views` (computed from its files when it was made or refreshed,
`generator/dataset_stats.py`); a dataset without `rgb.shadowed` is refused by name. Writes one row per
dataset and a last row `mean` (the mean of each column over the datasets), and prints the mean line.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from contracts.atomic import write_rows_csv  # noqa: E402

COLUMNS = ("psnr_smoky_vs_clean", "psnr_smoky_vs_shadowed", "psnr_shadowed_vs_clean")


def share_rows(datasets: list[Path]) -> list[dict[str, object]]:
    """One row per dataset and the mean row; SystemExit naming the first dataset that lacks a figure."""
    rows: list[dict[str, object]] = []
    for d in datasets:
        meta_path = d / "dataset.json"
        if not meta_path.is_file():
            raise SystemExit(f"{meta_path}: no dataset here")
        views = (json.loads(meta_path.read_text()).get("stats") or {}).get("test_views") or {}
        missing = [c for c in COLUMNS if not isinstance(views.get(c), (int, float))]
        if missing:
            raise SystemExit(f"{meta_path}: stats.test_views.{missing[0]} is missing (a dataset without rgb.shadowed, "
                             "or with statistics older than the pass: generate-benchmark adds the pass to a "
                             "finished dataset, generate-scene --update-stats recomputes its statistics)")
        rows.append({"dataset": d.name, **{c: float(views[c]) for c in COLUMNS}})
    rows.append({"dataset": "mean", **{c: float(np.mean([r[c] for r in rows])) for c in COLUMNS}})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/standard/shadow_share.csv")
    args = parser.parse_args()
    rows = share_rows([d.resolve() for d in args.datasets])
    write_rows_csv(args.out, rows)
    m = rows[-1]
    print(f"{len(rows) - 1} datasets, test views: smoky input {m['psnr_smoky_vs_clean']:.2f} dB against clean, "
          f"{m['psnr_smoky_vs_shadowed']:.2f} against shadowed; shadowed against clean "
          f"{m['psnr_shadowed_vs_clean']:.2f} (wrote {args.out})")


if __name__ == "__main__":
    main()
