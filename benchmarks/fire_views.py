"""Usage: python benchmarks/fire_views.py --tables data/tables_standard --out DIR DATASET [DATASET ...]
          [--variants full,rgb-only] [--seed 0] [--digest PREFIX] [--all-scenes]

The surface issue's fire check: for every scene with fire (dataset.json ``smoke.fire``), a figure
of every test view (smoky input, clean truth, each variant's de-smoked surface: OUT/SCENE.png) and
the share of the smoke's strong change to the frame each surface keeps (eval/smoke_kept.py;
OUT/smoke_kept.csv, one row per scene and variant). The runs are the finished table runs of one trainer version in
--tables (the digest starting with PREFIX, else the version with the most runs), at --seed.
--all-scenes takes the scenes without fire too (a plume core kept is smoke left in the surface
as well). A scene without fire, or without a finished run of a variant, is named in the log and left
out; nothing is written when no scene is left.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from contracts.atomic import write_rows_csv
from contracts.errors import DatasetError
from eval.finished_runs import runs_of_variants
from eval.runs import VARIANTS
from eval.smoke_kept import run_kept, write_fire_figure


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--tables", type=Path, required=True, help="a regenerate-tables output folder (its runs/)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--variants", default="full,rgb-only")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--digest", metavar="PREFIX", help="the trainer version whose runs to read")
    ap.add_argument("--all-scenes", action="store_true", help="scenes without fire too")
    args = ap.parse_args()
    variants = args.variants.split(",")
    runs = runs_of_variants(args.tables, args.variants, VARIANTS, args.digest)
    by_key = {(rec["scene"], rec["variant"]): run_dir for run_dir, rec in runs if rec["seed"] == args.seed}
    digest = runs[0][1]["code_digest"][:8]
    rows = []
    for dataset in args.datasets:
        meta_path = dataset / "dataset.json"
        try:
            meta = json.loads(meta_path.read_text())
            scene, fire = meta["scene"], bool(meta["smoke"]["fire"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            sys.exit(f"fire_views: {meta_path}: field scene or smoke.fire unreadable ({exc})")
        if not (fire or args.all_scenes):
            print(f"fire_views: {scene}: no fire (smoke.fire false): left out", flush=True)
            continue
        views: dict[str, list] = {}
        columns = ["smoky input", "clean"]
        for variant in variants:
            run_dir = by_key.get((scene, variant))
            if run_dir is None:
                print(f"fire_views: {scene}: no finished {variant} run of trainer {digest} at seed {args.seed}: "
                      "left out", flush=True)
                continue
            try:
                kept, images = run_kept(run_dir, dataset)
            except DatasetError as exc:
                sys.exit(f"fire_views: {exc}")
            metrics = json.loads((run_dir / "metrics.json").read_text())["metrics"]
            for stem, smoky, clean, surface in images:
                views.setdefault(stem, [smoky, clean]).append(surface)
            columns.append(variant)
            rows.append({"scene": scene, "fire": fire, "variant": variant, "seed": args.seed, "digest": digest,
                         "views": kept.views, "strong_pixels": kept.strong_pixels,
                         "strong_share": round(kept.strong_share, 5), "smoke_kept": round(kept.kept, 4),
                         "test_psnr": round(metrics["psnr"], 3), "input_psnr": round(metrics["psnr_input"], 3),
                         "run_dir": str(run_dir)})
            print({k: rows[-1][k] for k in ("scene", "variant", "strong_pixels", "smoke_kept", "test_psnr")}, flush=True)
        if len(columns) > 2:
            try:
                write_fire_figure(args.out / f"{scene}.png", columns, views)
            except ValueError as exc:
                sys.exit(f"fire_views: {scene}: the runs' test views differ ({exc})")
    if not rows:
        sys.exit("fire_views: no scene with a finished run to show; nothing written")
    write_rows_csv(args.out / "smoke_kept.csv", rows)


if __name__ == "__main__":
    main()
