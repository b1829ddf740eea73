"""Usage: python benchmarks/clean_ceiling.py --out runs/clean_ceiling DATASET [DATASET ...]
          [--modes full,rgb-only[,CANDIDATE...]] [--profile standard] [--seed 0] [--threads 1]
          [--csv FILE] [--finished-only [--digest PREFIX]]

The smoke-free ceiling of a scene: each method (Full and RGB-only, and any candidate of
eval/runs.py CANDIDATES: Full with its overrides), at the same profile and budget as the tables,
fed the clean renders instead of the smoky ones, RGB and thermal. No
de-smoking method can be expected to beat this number on the scene's test views, so where it is
under the smoky input's PSNR (thin smoke), "Full above the input" is out of reach at that budget
whatever the method does. With no smoke, thermal must cost nothing: Full's ceiling should match
RGB-only's.

Each scene gets a derived dataset (eval/clean_ceiling.py: links into the original, the clean
frames in place of the smoky ones, no smoke passes) and a `train-and-evaluate --mode MODE` run
beside it; both resume, and a finished run of other trainer code, profile, seed or (a candidate)
settings is retrained.
`--finished-only` trains and derives nothing: it tables the ceiling runs already finished in
OUT by today's trainer or, with `--digest PREFIX`, by the earlier trainer whose code digest starts
so (as `regenerate-tables --finished-only --digest`); a scene and method without one is named in
the log and left out of the CSV.

One CSV row per scene and method: ceiling test/validation PSNR, SSIM and LPIPS (with the record's
``lpips_status``: how and with which weights it was scored, the home folder written ~/) against
the smoky input's PSNR; the same method's Table 1 run on the smoky scene (same seed and trainer
digest, where the tables have it), its PSNR and LPIPS, and the share of the input-to-ceiling PSNR
gap it closes; and the test views split by the original dataset's smoke mask (eval/regions.py), so
the smoky pixels' ceiling can be set beside what the table methods reach there
(per_scene_regions.md).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from contracts.atomic import write_rows_csv
from contracts.errors import DatasetError
from contracts.source import code_digest
from eval.clean_ceiling import (ceiling_digests, ceiling_run, derive_clean_dataset, finished_ceiling,
                                 headroom_recovered, smoky_input_psnr, table_test_metrics)
from eval.finished_runs import pick_digest
from eval.harness import TRAINER_ENTRY
from eval.regions import score_run
from eval.report import home_as_tilde
from eval.runs import CANDIDATES, RunResult


def _rounded(value: float | None, digits: int) -> float | None:
    return None if value is None else round(value, digits)


def trainer_mode(key: str) -> tuple[str, dict[str, Any]]:
    """The trainer mode and config overrides of a ``--modes`` entry: a method or a candidate."""
    if key in CANDIDATES:
        return CANDIDATES[key].mode, dict(CANDIDATES[key].overrides)
    return key, {}


def set_args(settings: dict[str, Any]) -> list[str]:
    """``train-and-evaluate --set`` arguments for config overrides (each value written as JSON,
    which the trainer reads back as YAML)."""
    return [f"--set={k}={json.dumps(v)}" for k, v in settings.items()]


def train(dataset: Path, run_dir: Path, key: str, profile: str, seed: int, threads: int) -> dict:
    """The run of method or candidate ``key`` on the derived dataset by today's trainer
    (eval.clean_ceiling.ceiling_run: a run of other trainer code, profile, seed or settings is
    retrained, an interrupted one resumed)."""
    mode, settings = trainer_mode(key)

    def run(folder: Path) -> None:
        cmd = [str(Path(sys.executable).with_name("train-and-evaluate")), str(dataset), "--mode", mode,
               "--profile", profile, "--seed", str(seed), "--threads", str(threads), "--out", str(folder),
               "--no-progress", *set_args(settings)]
        print("running:", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True)

    return ceiling_run(run_dir, code_digest(TRAINER_ENTRY), profile, seed, run, settings)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--modes", default="full,rgb-only",
                    help="comma-separated methods (full, rgb-only) and candidates (eval/runs.py) to train on the clean frames")
    ap.add_argument("--profile", default="standard")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--tables", type=Path, default=Path("data/tables_standard/runs"),
                    help="table runs to read the smoky input's PSNR from")
    ap.add_argument("--csv", type=Path, help="default OUT/clean_ceiling.csv")
    ap.add_argument("--finished-only", action="store_true",
                    help="table the ceiling runs already finished in --out; derive and train nothing")
    ap.add_argument("--digest", metavar="PREFIX",
                    help="with --finished-only: table the runs of the trainer whose code digest starts so "
                         "(an earlier trainer's), in place of today's")
    args = ap.parse_args()
    modes = [m for m in args.modes.split(",") if m]
    bad = [m for m in modes if m not in ("full", "rgb-only") and m not in CANDIDATES]
    if not modes or bad:
        sys.exit(f"clean_ceiling: --modes: {','.join(bad) or 'nothing'} is not full, rgb-only or a candidate "
                 f"({', '.join(CANDIDATES)})")
    if args.digest and not args.finished_only:
        sys.exit("clean_ceiling: --digest: only with --finished-only (a run trains under today's trainer's digest)")
    trainer = code_digest(TRAINER_ENTRY)
    if args.digest:
        try:
            trainer = pick_digest(ceiling_digests(args.out), args.digest, str(args.out))
        except ValueError as exc:
            sys.exit(f"clean_ceiling: {exc}")
    rows, missing = [], []
    for src in args.datasets:
        if not args.finished_only:
            try:
                derived = derive_clean_dataset(src, args.out / src.name / "dataset")
            except (DatasetError, ValueError) as exc:
                sys.exit(f"clean_ceiling: {exc}")
        for mode in modes:
            run_dir = args.out / src.name / mode
            if args.finished_only:
                m = finished_ceiling(run_dir, trainer, args.profile, args.seed, trainer_mode(mode)[1])
                if m is None:
                    missing.append(f"{src.name} {mode}")
                    print(f"{run_dir}: no finished run of trainer {trainer[:8]} at {args.profile}, seed {args.seed} "
                          "(--finished-only): left out", flush=True)
                    continue
            else:
                m = train(derived, run_dir, mode, args.profile, args.seed, args.threads)
            val = m.get("validation") or {}
            digest = m["provenance"]["source_digest"][:8]
            input_test, input_val = smoky_input_psnr(src.name, args.profile, args.tables, digest)
            method = table_test_metrics(src.name, mode, args.seed, args.profile, digest, args.tables) or {}
            share = headroom_recovered(method.get("psnr"), input_test, m["metrics"]["psnr"])
            regions = {r.region: r for r in score_run(
                RunResult(src.name, f"clean-ceiling-{mode}", args.seed, "ok", str(run_dir), ""), src)}
            rows.append({
                "scene": src.name, "mode": mode, "profile": args.profile, "seed": args.seed,
                "ceiling_test_psnr": round(m["metrics"]["psnr"], 3),
                "ceiling_test_ssim": round(m["metrics"]["ssim"], 4),
                "ceiling_test_lpips": _rounded(m["metrics"].get("lpips"), 4),
                "ceiling_val_psnr": _rounded(val.get("psnr"), 3),
                "input_test_psnr": _rounded(input_test, 3),
                "input_val_psnr": _rounded(input_val, 3),
                "method_test_psnr": _rounded(method.get("psnr"), 3),
                "method_test_lpips": _rounded(method.get("lpips"), 4),
                "headroom_recovered": _rounded(share, 3),
                "smoky_pixel_share": round(regions["smoky"].pixel_share, 3),
                "ceiling_smoky_psnr": round(regions["smoky"].psnr, 2),
                "input_smoky_psnr": round(regions["smoky"].psnr_input, 2),
                "ceiling_clear_psnr": round(regions["clear"].psnr, 2),
                "input_clear_psnr": round(regions["clear"].psnr_input, 2),
                "wall_s": round(m["wall_time_s"]["total"], 1), "threads": m["provenance"]["threads"],
                "commit": m["provenance"]["commit"], "source_digest": digest,
                "lpips_status": home_as_tilde(m["metrics"].get("lpips_status") or "")})
            print({k: rows[-1][k] for k in ("scene", "mode", "ceiling_test_psnr", "headroom_recovered", "wall_s")},
                  flush=True)
    if missing:
        print(f"clean_ceiling: {len(missing)} left out, not finished by trainer {trainer[:8]}: {', '.join(missing)}",
              flush=True)
    if not rows:
        sys.exit(f"clean_ceiling: {args.out}: no finished ceiling run of trainer {trainer[:8]} to table; "
                 "nothing written")
    write_rows_csv(args.csv or args.out / "clean_ceiling.csv", rows)


if __name__ == "__main__":
    main()
