"""Does a simulation baked again give a finished dataset's smoke? The tolerance of the smoke check
that guards adding a pass to a finished dataset (`generator.ground_truth_refresh.SMOKE_CHECK_RMS`).

    python benchmarks/bake_reproduction.py data/standard/house [--seeds 107]

Bakes the dataset's recorded spec again (one bake, kept in a temporary bake store) and renders
its RGB smoke opacity at the dataset's own seed and at each other seed of `--seeds`. Per RGB frame:
the RMS and mean difference of each render against the dataset's opacity, of the other seeds
against the render at the dataset's seed (two renders of one bake: the Monte Carlo noise alone),
and of the dataset's next frame against each frame (the smoke's own motion in one frame: what a
different smoke at least looks like). RMS per pixel and over the check's blocks
(`SMOKE_CHECK_BLOCK`), what pixel noise alone leaves over a block, and the share of the check's
allowance each frame uses (`generator.ground_truth_refresh.opacity_difference`). Prints the
largest per-frame RMS of each comparison; writes benchmarks/results/bake_reproduction.csv.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from contracts.atomic import write_rows_csv
from contracts.dataset_format import PASS_FILES, file_path, transforms_name
from contracts.imageio import read_exr_channel
from generator.ground_truth_refresh import SMOKE_CHECK_BLOCK, opacity_difference, recorded_spec
from generator.pipeline import generate
from generator.spec import parse_passes

RESULTS = Path(__file__).resolve().parent / "results"
ALPHA = PASS_FILES[("rgb", "smoke_alpha")][0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--seeds", default="107", help="comma-separated render seeds besides the dataset's")
    args = parser.parse_args()
    record = recorded_spec(args.dataset)
    if record is None:
        raise SystemExit(f"{args.dataset}: no readable dataset.json and scene.yaml")
    spec = replace(record[0], passes=parse_passes("rgb.smoke_alpha", "benchmark"))
    seeds = [spec.seed] + [int(s) for s in args.seeds.split(",") if s.strip()]
    stems = [f["file_stem"] for f in json.loads((args.dataset / transforms_name("rgb")).read_text())["frames"]]

    def alphas(root: Path) -> list[np.ndarray]:
        return [read_exr_channel(file_path(root, ALPHA, s), "A").astype(np.float64) for s in stems]

    committed = alphas(args.dataset)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        renders = {seed: alphas(generate(replace(spec, seed=seed), Path(tmp) / f"seed{seed}", force=True,
                                         show_progress=False, bake_store=Path(tmp) / "bakes"))
                   for seed in seeds}
    comparisons = {f"seed {seed} vs dataset": (renders[seed], committed) for seed in seeds}
    comparisons.update({f"seed {seed} vs seed {spec.seed}": (renders[seed], renders[spec.seed]) for seed in seeds[1:]})
    comparisons["dataset next frame vs frame"] = (committed[1:], committed[:-1])
    rows = []
    for name, (a, b) in comparisons.items():
        for stem, x, y in zip(stems, a, b):
            d = opacity_difference(x, y)
            rows.append({"dataset": args.dataset.name, "comparison": name, "frame": stem, "rms": d.pixel_rms,
                         "block_rms": d.block_rms, "noise_block_rms": d.noise_block_rms,
                         "share_of_allowed": d.share_of_allowed,
                         "mean_difference": float(np.mean(x - y)), "mean_alpha": float(np.mean(y))})
        mine = [r for r in rows if r["comparison"] == name]
        print(f"{name}: largest per-frame RMS {max(r['rms'] for r in mine):.4f} per pixel, "
              f"{max(r['block_rms'] for r in mine):.4f} over {SMOKE_CHECK_BLOCK}-pixel blocks "
              f"(smallest {min(r['block_rms'] for r in mine):.4f}); share of the check's allowance "
              f"{min(r['share_of_allowed'] for r in mine):.2f}-{max(r['share_of_allowed'] for r in mine):.2f}; "
              f"mean difference "
              f"{np.mean([r['mean_difference'] for r in mine]):+.5f} (mean alpha "
              f"{np.mean([r['mean_alpha'] for r in mine]):.4f})")
    print("the smoke check refuses a frame whose share of its allowance is over 1")
    print(f"load average {load_before:.2f} before, {os.getloadavg()[0]:.2f} after")
    write_rows_csv(RESULTS / "bake_reproduction.csv", rows)


if __name__ == "__main__":
    main()
