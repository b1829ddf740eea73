"""How far a result moves when the smoky RGB frames move by one 8-bit level: a rule that holds
should not flip on noise a camera adds anyway (rules issue: ≤ 0.2 dB of test PSNR on machine,
room and food_plate).

    python -m benchmarks.input_perturbation --out data/input_perturbation [--scenes machine,room,food_plate]
        [--datasets data/standard] [--levels 1] [--noise-seed 1] [--profile standard] [--seed 0] [--workers 2]
        [--originals-from data/tables_standard] [--csv benchmarks/results/input_perturbation/per_scene.csv]
        [--compare-only]

For each scene a copy of its dataset is written under OUT/datasets/SCENE-noisyLEVELS, identical
but for the smoky RGB frames: each 8-bit value moves up or down by ``--levels`` (the sign drawn per
value from ``--noise-seed``, clipped at 0 and 255), and `perturbation.json` beside dataset.json says
so. Then `regenerate-tables` trains Full at one seed on the copies (OUT/tables) and on the
originals (OUT/tables too, or a tables folder that already holds them: ``--originals-from``, read
before OUT/tables); both are resumable, and the run key holds each dataset's hash, so the two
never share a run. The CSV has one row per scene and trainer version that finished both:
``scene, original_psnr, perturbed_psnr``, the difference, both validation PSNRs, the trainer and
the original's folder.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import full_seed_runs
from contracts.atomic import write_json
from contracts.imageio import read_png, write_png
from eval.finished_runs import runs_by_version

ROOT = Path(__file__).resolve().parents[1]
SMOKY = Path("rgb") / "smoky"
LIMIT_DB = 0.2
"""The rules issue's bound on the move of the test PSNR."""


def noisy_name(scene: str, levels: int) -> str:
    return f"{scene}-noisy{levels}"


def perturb_dataset(src: Path, dst: Path, levels: int, noise_seed: int) -> dict[str, Any]:
    """Write ``dst``: ``src`` with every smoky RGB value moved by ±``levels`` (clipped). Staged beside
    ``dst`` and renamed into place, so a stopped copy is never read as a dataset; a finished copy of
    the same source and noise is kept."""
    record = {"source": str(src), "pass": "rgb.smoky", "levels": levels, "noise_seed": noise_seed,
              "noise": "each 8-bit value of each smoky RGB frame moved by +levels or -levels, the sign drawn "
                       "uniformly per value, clipped to 0..255"}
    done = dst / "perturbation.json"
    if done.is_file():
        kept = json.loads(done.read_text())
        if {k: kept.get(k) for k in record} == record:
            return kept
        raise ValueError(f"{dst}: holds another perturbation ({done}); remove it or choose another --out")
    staging = dst.parent / f".{dst.name}.partial"
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(src, staging)
    rng = np.random.default_rng(noise_seed)
    frames = sorted((staging / SMOKY).glob("*.png"))
    if not frames:
        raise ValueError(f"{src / SMOKY}: no smoky RGB frames")
    moved, clipped = 0.0, 0
    for path in frames:  # sorted, so the draws follow the frame order
        image = read_png(path).astype(np.int16)
        step = np.where(rng.random(image.shape) < 0.5, -levels, levels).astype(np.int16)
        noisy = np.clip(image + step, 0, 255)
        clipped += int(((image + step) != noisy).sum())
        moved += float(np.abs(noisy - image).mean())
        write_png(path, noisy.astype(np.uint8))
    record.update(frames=len(frames), mean_abs_change_levels=round(moved / len(frames), 4), clipped_values=clipped)
    write_json(staging / "perturbation.json", record)
    staging.rename(dst)
    return record


def compare(perturbed_tables: Path, original_tables: list[Path], scenes: list[str], levels: int,
            seed: int) -> list[dict[str, Any]]:
    """One row per scene and trainer version whose original and perturbed runs both finished (a
    scene's two runs are compared only under one trainer). The original is looked for in
    ``original_tables`` in order; the row names the folder it came from."""
    def by_version(tables: Path) -> dict[tuple[str, str], tuple[Path, dict[str, Any]]]:
        return {key: variants["full"] for key, variants in runs_by_version(tables, ["full"], seed).items()}
    perturbed = by_version(perturbed_tables)
    originals: dict[tuple[str, str], tuple[Path, dict[str, Any], Path]] = {}
    for tables in original_tables:
        for key, (run, rec) in by_version(tables).items():
            originals.setdefault(key, (run, rec, tables))
    rows = []
    for (scene, digest), (o_run, o_rec, where) in sorted(originals.items()):
        if scene not in scenes or (noisy_name(scene, levels), digest) not in perturbed:
            continue
        p_run, p_rec = perturbed[noisy_name(scene, levels), digest]
        o, p = float(o_rec["metrics"]["psnr"]), float(p_rec["metrics"]["psnr"])
        rows.append({"scene": scene, "original_psnr": round(o, 4), "perturbed_psnr": round(p, 4),
                     "perturbed_minus_original": round(p - o, 4), "original_val_psnr": full_seed_runs.validation_psnr(o_run),
                     "perturbed_val_psnr": full_seed_runs.validation_psnr(p_run), "levels": levels,
                     "trainer": digest[:8], "originals_from": str(where)})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.input_perturbation", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True, help="OUT/datasets holds the copies, OUT/tables the runs")
    full_seed_runs.add_arguments(p, "machine,room,food_plate", "benchmarks/results/input_perturbation/per_scene.csv")
    p.add_argument("--levels", type=int, default=1, help="8-bit levels each smoky value moves by")
    p.add_argument("--noise-seed", type=int, default=1)
    p.add_argument("--originals-from", type=Path,
                   help="a tables folder that holds (or will hold) the runs on the original datasets")
    args = p.parse_args(argv)
    scenes = full_seed_runs.scenes_of(args, "input_perturbation")
    if scenes is None:
        return 2
    if not 1 <= args.levels <= 64:
        print(f"input_perturbation: error: --levels: 1 to 64 8-bit levels, got {args.levels}", file=sys.stderr)
        return 2
    tables = args.out / "tables"
    originals = args.originals_from or tables
    if not args.compare_only:
        copies: dict[str, Path] = {}
        for s in scenes:
            copy = args.out / "datasets" / noisy_name(s, args.levels)
            try:
                rec = perturb_dataset(args.datasets / s, copy, args.levels, args.noise_seed)
            except ValueError as exc:
                print(f"input_perturbation: error: {exc}", file=sys.stderr)
                return 2
            print(f"{s}: {rec['frames']} smoky frames moved by ±{args.levels} (mean |change| "
                  f"{rec['mean_abs_change_levels']} levels, {rec['clipped_values']} values clipped) in {copy}")
            copies[noisy_name(s, args.levels)] = copy
        sources = {s: args.datasets / s for s in scenes}
        calls = ([({**sources, **copies}, tables)] if originals == tables  # one call, two workers across both
                 else [(sources, originals), (copies, tables)])
        for datasets, out in calls:
            done = subprocess.run(full_seed_runs.tables_command(datasets, args.profile, args.seed, args.workers, out),
                                  cwd=ROOT)
            if done.returncode not in (0, 1):  # 1: tables written, some runs failed
                return done.returncode
    rows = compare(tables, list(dict.fromkeys([originals, tables])), scenes, args.levels, args.seed)
    if not full_seed_runs.write_pairs("input_perturbation", args.csv, rows, ("original", "perturbed"),
                                      "perturbed_minus_original",
                                      f"{tables}: no scene of {', '.join(scenes)} has both runs "
                                      "finished under one trainer"):
        return 2
    worst = max(abs(r["perturbed_minus_original"]) for r in rows)
    print(f"largest move {worst:.3f} dB (limit {LIMIT_DB} dB) over {len(rows)} pairs "
          f"({len({r['scene'] for r in rows})} of {len(scenes)} scenes); wrote {args.csv}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
