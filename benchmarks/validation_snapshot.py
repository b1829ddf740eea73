"""What keeping Stage 3's best validation snapshot would give, read off a table's finished runs.

    python benchmarks/validation_snapshot.py [--tables data/tables_standard] [--digest PREFIX]

A standard run logs the validation and test PSNR every 250 Stage-3 iterations. Keeping the state
of the logged iteration with the best validation PSNR (early stopping, chosen on validation views
only) would have scored that iteration's test PSNR. This reads each finished Full and RGB-only
run of one trainer version (``--digest``, default: the version with the most runs) and writes
``benchmarks/results/standard/validation_snapshot.csv`` (one row per run: the final and the
selected iteration's test PSNR) and prints the per-scene seed means of both, so the gain can be
set against the Full − RGB-only gap without training anything.
"""
from __future__ import annotations

import argparse
import collections
import statistics
from pathlib import Path

from contracts.atomic import write_rows_csv
from contracts.train_log import read_train_log
from eval.finished_runs import finished_runs

VARIANTS = ("full", "rgb-only")


def run_rows(tables: Path, digest: str | None) -> list[dict[str, object]]:
    """One row per finished Full or RGB-only run of the chosen trainer version."""
    rows = []
    for folder, rec in finished_runs(tables, VARIANTS, digest)[1]:
        logged = [r for r in read_train_log(folder / "train_log.csv") if r["stage"] == "3" and r["val_psnr"]]
        best = max(logged, key=lambda r: float(r["val_psnr"]))
        rows.append({"scene": rec["scene"], "variant": rec["variant"], "seed": rec["seed"],
                     "code_digest": rec["code_digest"][:8], "final_iteration": int(logged[-1]["iteration"]),
                     "final_val_psnr": float(logged[-1]["val_psnr"]), "final_test_psnr": float(logged[-1]["test_psnr"]),
                     "selected_iteration": int(best["iteration"]), "selected_val_psnr": float(best["val_psnr"]),
                     "selected_test_psnr": float(best["test_psnr"])})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tables", type=Path, default=Path("data/tables_standard"))
    ap.add_argument("--digest", default=None, help="trainer code digest prefix (default: the one with the most runs)")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/standard/validation_snapshot.csv"))
    args = ap.parse_args()
    try:
        rows = run_rows(args.tables, args.digest)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    write_rows_csv(args.out, rows)
    by = collections.defaultdict(list)
    for r in rows:
        by[r["scene"], r["variant"]].append(r)
    means = collections.defaultdict(list)
    print(f"{'scene':11s} " + " ".join(f"{v + ' final':>15s} {v + ' selected':>18s}" for v in VARIANTS))
    for scene in sorted({s for s, _ in by}):
        cells = []
        for v in VARIANTS:
            runs = by.get((scene, v), [])
            fin = statistics.mean(r["final_test_psnr"] for r in runs) if runs else float("nan")
            sel = statistics.mean(r["selected_test_psnr"] for r in runs) if runs else float("nan")
            means[v, "final"].append(fin)
            means[v, "selected"].append(sel)
            cells.append(f"{fin:15.2f} {sel:18.2f}")
        print(f"{scene:11s} " + " ".join(cells))
    print(f"{'mean':11s} " + " ".join(f"{statistics.mean(means[v, 'final']):15.2f} "
                                      f"{statistics.mean(means[v, 'selected']):18.2f}" for v in VARIANTS))
    print(f"{len(rows)} runs, trainer {rows[0]['code_digest']}; wrote {args.out}")


if __name__ == "__main__":
    main()
