"""Where Stage 3 starts: validation PSNR of each candidate surface before any Stage-3 step.

    python benchmarks/surface_union_start.py DATASET RUN_DIR [--seed 0] [--shares 0.25 0.5] [--out CSV]

RUN_DIR is a finished two-surface run (``--set stage3.surface_init=thermal+rgb`` or
``rgb+thermal-fill``) of DATASET at the standard profile; its ``checkpoints/stage2.pt`` and
``stage2_rgb.pt`` are read, never written (they are copied to a scratch folder). Every surface is
scored as the trainer scores a run, surface only, on the validation views, with the RGB Stage 2's
environment behind it and no smoke yet:
- the RGB Stage 2 (where RGB-only's Stage 3 starts), and the same carved by the thermal depth;
- the thermal Stage 2 alone, its RGB colours borrowed from the nearest kept RGB Gaussian;
- ``thermal+rgb`` (every thermal Gaussian joins) and ``rgb+thermal-fill`` at each share.
Writes one row per surface (appended to ``--out`` with the scene, seed and count).
"""
from __future__ import annotations

import argparse
import csv
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from contracts.atomic import write_rows_csv
from smokeseer.api import _init_points, prepare
from smokeseer.evaluation.scoring import split_psnr
from smokeseer.model.gaussians import GaussianSet
from smokeseer.model.scene import SceneModel
from smokeseer.train.depth_prior import rendered_depth_prior
from smokeseer.train.stage2 import train_stage2, views_of
from smokeseer.train.surface_union import join_surfaces
from smokeseer.train.util import RunContext, RunLog

FIELDS = ["scene", "seed", "surface", "fill_opaque_share", "thermal_gaussians", "rgb_gaussians", "val_psnr"]


def _subset(g: GaussianSet, rows: torch.Tensor) -> GaussianSet:
    return GaussianSet({k: v.detach()[rows].clone() for k, v in g.state_dict().items()})


def _check_finished(path: Path, sha: str) -> None:
    """The benchmark scores checkpoints; it never trains a Stage 2 of its own."""
    payload = torch.load(path, weights_only=False, map_location="cpu")
    if not payload.get("done") or payload.get("config_sha256") != sha:
        raise SystemExit(f"{path}: not a finished Stage 2 with this dataset's standard settings (done, config_sha256)")


def measure(dataset: Path, run: Path, seed: int, shares: list[float]) -> list[dict[str, object]]:
    """The dataset, both Stage 2s and the thermal depth are read once; each surface is a join."""
    rows: list[dict[str, object]] = []
    prep = prepare(dataset, "full", "standard", seed, {"stage3.surface_init": "thermal+rgb"})
    cfg, scene, b = prep.cfg, prep.scene, prep.report.bounds
    dev = torch.device("cpu")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        (work / "checkpoints").mkdir()
        for name in ("stage2.pt", "stage2_rgb.pt"):
            shutil.copy(run / "checkpoints" / name, work / "checkpoints" / name)
        log = RunLog(work / "log.csv")
        center = torch.as_tensor(b.center, dtype=torch.float32)
        ctx = RunContext(cfg, work, log, center, b.extent)
        _check_finished(work / "checkpoints" / "stage2.pt", ctx.stage2_sha)
        _check_finished(work / "checkpoints" / "stage2_rgb.pt", replace(cfg, mode="rgb-only").stage2_sha256())
        s2 = train_stage2(ctx, scene.thermal, _init_points(scene, scene.thermal, cfg.stage2.init_points, b,
                                                           np.random.default_rng(seed)), deformable=False)
        depth = rendered_depth_prior(s2.gaussians, views_of(scene.rgb, scene.rgb.indices("train"), dev), "rgb")
        rgb_init = _init_points(scene, scene.rgb, cfg.stage2.init_points, b, np.random.default_rng(seed))

        def row(surface: str, g: GaussianSet, n_thermal: int, share: float | None, background: object) -> None:
            m = SceneModel(g, None, None, True, ctx.center, cfg.sh_degree, background_rgb=background)
            rows.append({"scene": scene.name, "seed": seed, "surface": surface, "fill_opaque_share": share,
                         "thermal_gaussians": n_thermal, "rgb_gaussians": g.n - n_thermal,
                         "val_psnr": round(float(split_psnr(m, scene, dev, "val")), 3)})

        for init, share in [("thermal+rgb", None)] + [("rgb+thermal-fill", s) for s in shares]:
            stage3 = replace(cfg.stage3, surface_init=init,
                             fill_opaque_share=cfg.stage3.fill_opaque_share if share is None else share)
            joined = join_surfaces(RunContext(replace(cfg, stage3=stage3), work, log, center, b.extent),
                                   scene.rgb, rgb_init, s2, depth)
            n_th, bg = joined.record["thermal_kept"], joined.rgb.background
            if init == "thermal+rgb":
                rgb_rows = torch.zeros(joined.surface.n, dtype=torch.bool)
                rgb_rows[n_th:] = True
                row("rgb stage 2", joined.rgb.gaussians, 0, None, bg)
                row("rgb stage 2, carved", _subset(joined.surface, rgb_rows), 0, None, bg)
                row("thermal stage 2, borrowed colours", _subset(joined.surface, ~rgb_rows), n_th, None, bg)
            row(init, joined.surface, n_th, share, bg)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("run", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--shares", type=float, nargs="+", default=[0.25, 0.5])
    ap.add_argument("--out", type=Path,
                    default=Path(__file__).resolve().parent / "results" / "full_candidates" / "surface_start.csv")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    t = time.perf_counter()
    rows = measure(args.dataset, args.run, args.seed, args.shares)
    old = []
    if args.out.exists():
        with args.out.open() as f:
            old = [r for r in csv.DictReader(f)
                   if not (r["scene"] == rows[0]["scene"] and int(r["seed"]) == args.seed)]
    write_rows_csv(args.out, [{k: r[k] for k in FIELDS} for r in old + rows])
    for r in rows:
        print(f"{r['scene']} seed {r['seed']}: {r['surface']:<36} share {r['fill_opaque_share']!s:<5} "
              f"{r['thermal_gaussians']:>6} thermal + {r['rgb_gaussians']:>6} RGB: {r['val_psnr']:.2f} dB")
    print(f"{time.perf_counter() - t:.0f} s -> {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
