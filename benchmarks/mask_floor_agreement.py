"""How well the mask floor read off the images agrees with the generator's truth.

    python benchmarks/mask_floor_agreement.py data/standard/house data/standard/room ... [--every 3]

The standard profile's mask floor acts on masked training pixels whose smoke may be dense
(``loss.mask_floor_where=estimated-meeting``, ``smokeseer/train/mask_floor.py``), read off the smoky
frames. Its target is where the true smoke alpha reaches the floor (0.4), which training cannot
read. For each dataset this computes both on the RGB training frames of the standard split, with
the dataset's own depth as the geometry (a trained Stage 2 renders a rougher one) and the point
where the haze lines meet on it (the profile's settings), and reports the share of masked pixels each marks, and the
estimate's precision and recall against the truth. ``never-clear`` (a point no other view sees
smoke-free) is reported beside it. Every ``--every``-th training frame is a reference.

Writes ``benchmarks/results/mask_floor_agreement.csv``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from contracts.atomic import write_rows_csv
from contracts.imageio import read_exr_channel
from scenes.images import box_downscale
from scenes.load import load_scene
from smokeseer.config import make_config
from smokeseer.stage1.haze_lines import HazeLineSettings, estimate_smoke_colour
from smokeseer.train.mask_floor import estimated_dense, never_seen_clear

RESULTS = Path(__file__).resolve().parent / "results"


def true_alpha(path: Path, stems: list[str], shape: tuple[int, int]) -> np.ndarray:
    maps = []
    for stem in stems:
        alpha = read_exr_channel(path / "rgb" / "smoke_alpha" / f"{stem}.exr", "A").astype(np.float64)
        maps.append(box_downscale(alpha, alpha.shape[1] // shape[1]))
    return np.stack(maps)


def measure(path: Path, every: int) -> dict[str, object]:
    cfg = make_config("full", "standard")
    t0 = time.perf_counter()
    scene = load_scene(path, cfg.max_width, validation_every=cfg.validation_every, all_ground_truth=True)
    rgb = scene.rgb
    train = rgb.indices("train")
    images, masks, depth = rgb.images[train], rgb.masks[train], rgb.depth[train].astype(np.float64)
    valid = depth > 0
    viewmats, Ks = rgb.cameras("train")
    colour = estimate_smoke_colour(images, depth, valid, viewmats, Ks, np.random.default_rng(cfg.seed + 2),
                                   HazeLineSettings.of(cfg.stage3))
    floor = cfg.loss.mask_alpha_floor
    estimated = estimated_dense(masks, images, depth, valid, viewmats, Ks, colour.meeting, floor)
    never = never_seen_clear(masks, depth, valid, viewmats, Ks)
    truth = true_alpha(path, [rgb.frames[i].file_stem for i in train], images.shape[1:3]) >= floor
    refs = np.arange(len(train)) % every == 0
    masked = (masks > 0.5)[refs]
    truth, estimated, never = truth[refs] & masked, estimated[refs] & masked, never[refs] & masked
    n = max(int(masked.sum()), 1)
    return {
        "scene": path.name,
        "masked_share": round(float(masked.mean()), 4),
        "true_dense_share": round(truth.sum() / n, 4),
        "estimated_share": round(estimated.sum() / n, 4),
        "estimated_precision": round((truth & estimated).sum() / max(int(estimated.sum()), 1), 4),
        "estimated_recall": round((truth & estimated).sum() / max(int(truth.sum()), 1), 4),
        "never_clear_share": round(never.sum() / n, 4),
        "never_clear_precision": round((truth & never).sum() / max(int(never.sum()), 1), 4),
        "never_clear_recall": round((truth & never).sum() / max(int(truth.sum()), 1), 4),
        "smoke_colour": "" if colour.colour is None else " ".join(f"{c:.3f}" for c in colour.colour),
        "meeting_point": "" if colour.meeting is None else " ".join(f"{c:.3f}" for c in colour.meeting),
        "seconds": round(time.perf_counter() - t0, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--every", type=int, default=3, help="every n-th training frame is a reference")
    args = ap.parse_args()
    rows = []
    for path in args.datasets:
        rows.append(measure(path, args.every))
        print(" ".join(f"{k}={v}" for k, v in rows[-1].items()), flush=True)
    write_rows_csv(RESULTS / "mask_floor_agreement.csv", rows)


if __name__ == "__main__":
    main()
