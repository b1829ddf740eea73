"""Validation PSNR of the standard profile's mask floor read off the images, against the committed
runs whose floor read the generator's true smoke alpha.

    python benchmarks/mask_floor_validation.py RUN_DIR ... [--tables data/tables_standard]

Each RUN_DIR is a finished ``train-and-evaluate DATASET --profile standard --seed 0`` run
whose mask floor is read off the images. Its last logged validation and test PSNR are set beside
the Full and RGB-only runs of the same scene and seed at trainer 6663d970, the last tables
trained with the true-alpha floor. Writes ``benchmarks/results/mask_floor_validation.csv``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from contracts.atomic import write_rows_csv
from contracts.train_log import read_train_log
from full_candidates import committed_run

RESULTS = Path(__file__).resolve().parent / "results"
TRUE_ALPHA_TRAINER = "6663d970"


def last_scores(run: Path) -> dict:
    """The run's last validation row and its metrics: scene, seed, PSNRs, Gaussian counts."""
    doc = json.loads((run / "metrics.json").read_text())
    if doc.get("status") != "ok":
        raise ValueError(f"{run / 'metrics.json'}: status: {doc.get('status')!r}, not a finished run")
    rows = [r for r in read_train_log(run / "train_log.csv") if r.get("val_psnr")]
    if not rows:
        raise ValueError(f"{run / 'train_log.csv'}: val_psnr: no validation row")
    return {"scene": doc["scene"], "seed": int(doc["seed"]), "val": float(rows[-1]["val_psnr"]),
            "test": float(doc["metrics"]["psnr"]), "surface": int(rows[-1]["n_gaussians"]),
            "smoke": int(rows[-1]["n_smoke"] or 0), "digest": doc["provenance"]["source_digest"][:8]}


def committed(tables: Path, scene: str, method: str, seed: int) -> dict:
    return last_scores(committed_run(tables, scene, method, seed, TRUE_ALPHA_TRAINER))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--tables", type=Path, default=Path("data/tables_standard"))
    args = p.parse_args(argv)
    rows = []
    try:
        for run in args.runs:
            est = last_scores(run)
            full = committed(args.tables, est["scene"], "full", est["seed"])
            rgb = committed(args.tables, est["scene"], "rgb-only", est["seed"])
            rows.append({"scene": est["scene"], "seed": est["seed"], "estimated_val_psnr": round(est["val"], 3),
                         "estimated_test_psnr": round(est["test"], 3), "estimated_surface": est["surface"],
                         "estimated_smoke": est["smoke"], "estimated_trainer": est["digest"],
                         "true_alpha_val_psnr": round(full["val"], 3), "true_alpha_test_psnr": round(full["test"], 3),
                         "rgb_only_val_psnr": round(rgb["val"], 3), "rgb_only_test_psnr": round(rgb["test"], 3),
                         "committed_trainer": TRUE_ALPHA_TRAINER})
    except (OSError, ValueError, KeyError) as exc:
        print(f"mask_floor_validation: error: {exc}", file=sys.stderr)
        return 2
    out = RESULTS / "mask_floor_validation.csv"
    write_rows_csv(out, rows)
    for r in rows:
        print(f"{r['scene']}: validation {r['estimated_val_psnr']:.2f} dB (true-alpha floor {r['true_alpha_val_psnr']:.2f}, "
              f"RGB-only {r['rgb_only_val_psnr']:.2f})")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
