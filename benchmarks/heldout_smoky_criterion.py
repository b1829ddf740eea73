"""Can a run tell, from what a capture has, when Stage 3 peaked? Held-out smoky frames against
the clean-frame validation PSNR, through one training run.

    python benchmarks/heldout_smoky_criterion.py data/standard/excavator --out runs/criterion/excavator \
        [--mode full] [--profile standard] [--seed 0] [--csv benchmarks/results/full_candidates/heldout_smoky_criterion.csv]

Keeping Stage 3's best clean-validation state would raise the standard tables' Full by 0.29 dB
(``benchmarks/validation_snapshot.py``), but a run cannot read clean frames: a capture has none.
It does have held-out smoky frames. This trains one run with ``train_and_evaluate`` and, each
time the trainer logs its held-out PSNRs (every ``stage3.test_every`` iterations), also scores the
full render (surface and smoke) against the smoky validation frames, which no training step
sees. The trainer's own numbers are untouched: its held-out hook is wrapped, not replaced, and
the run's train_log.csv and metrics.json are the ones it writes anyway. The CSV gives, per logged
Stage-3 iteration, the clean validation PSNR (surface only), the smoky validation PSNR (full
render), and the test PSNR, so both criteria's picks can be read off against the test views. A
CSV that already holds other runs keeps them; this run's rows replace any of the same scene, mode
and seed.
"""
from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

import numpy as np
import torch

import smokeseer.api as api
from contracts.atomic import write_rows_csv
from contracts.metrics import psnr
from contracts.train_log import read_train_log
from scenes.scene import SceneData
from smokeseer.config import make_config
from smokeseer.evaluation.scoring import split_views
from smokeseer.model.scene import SceneModel


def smoky_validation_psnr(model: SceneModel, scene: SceneData, device: torch.device) -> float | None:
    """Mean PSNR of the full render (surface and smoke) against the smoky validation frames."""
    idx, views = split_views(scene, device, "val")
    if not idx:
        return None
    with torch.no_grad():
        imgs = [model.render_rgb(v, smoke=True).colors[0].clamp(0, 1).cpu().numpy() for v in views]
    return float(np.mean([psnr(img, scene.rgb.images[i]) for i, img in zip(idx, imgs)]))


def merge_rows(target: Path, rows: list[dict[str, Any]]) -> None:
    """Write ``rows`` (one run's) into ``target``, keeping the rows of every other run there."""
    runs = {(str(r["scene"]), str(r["mode"]), str(r["seed"])) for r in rows}
    kept = ([r for r in csv.DictReader(open(target)) if (r["scene"], r["mode"], r["seed"]) not in runs]
            if target.is_file() else [])
    write_rows_csv(target, kept + rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--out", type=Path, required=True, help="the run folder (resumes if it holds a checkpoint)")
    ap.add_argument("--mode", default="full")
    ap.add_argument("--profile", default="standard")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--csv", type=Path, default=None, help="default: OUT/heldout_smoky_criterion.csv")
    args = ap.parse_args()
    if make_config(args.mode, args.profile, args.seed).validation_every == 0:
        raise SystemExit(f"--profile {args.profile}: has no validation views (validation_every 0), so there is "
                         "nothing held out to score; use a profile that holds some out, such as standard")
    smoky: list[float | None] = []
    trainer_hook = api.heldout_psnr

    def hook(model: SceneModel, scene: SceneData, device: torch.device) -> dict[str, Any]:
        smoky.append(smoky_validation_psnr(model, scene, device))
        return trainer_hook(model, scene, device)

    api.heldout_psnr = hook
    try:
        api.train_and_evaluate(args.dataset, args.out, args.mode, args.profile, args.seed, {"progress": False})
    finally:
        api.heldout_psnr = trainer_hook
    logged = [r for r in read_train_log(args.out / "train_log.csv") if r["stage"] == "3" and r["val_psnr"]]
    if len(logged) != len(smoky):
        raise SystemExit(f"{args.out}/train_log.csv: {len(logged)} logged Stage-3 evaluations but {len(smoky)} "
                         "scored here (a resumed run logs evaluations this process did not see; use a fresh --out)")
    rows = [{"scene": args.dataset.name, "mode": args.mode, "seed": args.seed, "iteration": int(r["iteration"]),
             "val_clean_psnr": float(r["val_psnr"]), "val_smoky_psnr": s, "test_psnr": float(r["test_psnr"])}
            for r, s in zip(logged, smoky)]
    merge_rows(args.csv or args.out / "heldout_smoky_criterion.csv", rows)
    for key in ("val_clean_psnr", "val_smoky_psnr"):
        best = max(rows, key=lambda r: r[key])
        print(f"{args.dataset.name} {args.mode} seed {args.seed}: best {key} at {best['iteration']} "
              f"-> test {best['test_psnr']:.2f} (final {rows[-1]['test_psnr']:.2f})")


if __name__ == "__main__":
    main()
