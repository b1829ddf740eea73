"""Weight-free smoke-mask candidates against the synthetic ground-truth masks.

    python benchmarks/smoke_masks.py DATASET [DATASET ...]

Each candidate (smokeseer/stage1/smoke_masks.py, and the multi-view residual of
smokeseer/stage1/smoke_presence.py that ``stage1=estimate`` uses) is scored by IoU per frame against the dataset's
``rgb/smoke_mask``. The candidate and threshold are chosen by the mean IoU over the
*validation* frames (the training views of every dataset given); the *test* views are only
scored afterwards. Writes benchmarks/results/smoke_masks.csv (every candidate, threshold,
scene and split, plus the trivial all-pixels mask as a reference), smoke_masks_choice.csv (the
chosen one per scene), smoke_masks.png (validation IoU against threshold) and
smoke_presence.csv (the presence decision ``stage1=estimate`` makes per scene, beside the
dataset's own flag).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from contracts.atomic import write_rows_csv  # noqa: E402
from scenes.load import load_scene  # noqa: E402
from smokeseer.stage1.smoke_masks import CANDIDATES, candidate_scores, iou  # noqa: E402
from smokeseer.stage1.smoke_presence import ESTIMATOR, decide_smoke_presence  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
THRESHOLDS = np.round(np.concatenate([[0.01, 0.02, 0.03], np.arange(0.05, 0.96, 0.05)]), 3)
ALL_CANDIDATES = CANDIDATES + (ESTIMATOR,)
"""The multi-view residual is binary (above the smoke-free floor): the same at every threshold."""
REFERENCE = "all-pixels"
"""The trivial mask that calls every pixel smoke: a candidate must beat it to be worth anything."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("datasets", nargs="+", type=Path, help="datasets with rgb/smoke_mask (generate-scene output)")
    ap.add_argument("--out", type=Path, default=RESULTS, help="folder for the CSV and PNG")
    args = ap.parse_args()
    rows = []
    presence: list[dict] = []
    for path in args.datasets:
        scene = load_scene(path)
        if scene.rgb.masks is None:
            raise SystemExit(f"{path}: no ground-truth smoke masks (pass smoke_alpha)")
        images = scene.rgb.images.astype(np.float64)
        decision = decide_smoke_presence(images, scene.rgb.frames, scene.rgb.indices("train"))
        presence.append({"scene": scene.name, "statistic": decision.statistic, "threshold": decision.threshold,
                         "decided_present": decision.present, "dataset_present": scene.smoke_present})
        for cand in ALL_CANDIDATES:
            scores = decision.masks if cand == ESTIMATOR else candidate_scores(images, cand)
            for thr in THRESHOLDS:
                for split, name in (("train", "validation"), ("test", "test")):
                    idx = scene.rgb.indices(split)
                    vals = [iou(scores[i] > thr, scene.rgb.masks[i]) for i in idx]
                    rows.append({"candidate": cand, "threshold": float(thr), "scene": scene.name, "split": name,
                                 "frames": len(idx), "iou": float(np.mean(vals)) if vals else float("nan")})
        for split, name in (("train", "validation"), ("test", "test")):
            idx = scene.rgb.indices(split)
            vals = [iou(np.ones_like(scene.rgb.masks[i]), scene.rgb.masks[i]) for i in idx]
            rows.append({"candidate": REFERENCE, "threshold": 0.0, "scene": scene.name, "split": name,
                         "frames": len(idx), "iou": float(np.mean(vals)) if vals else float("nan")})
        print(f"{scene.name}: scored {len(ALL_CANDIDATES)} candidates; ground truth covers "
              f"{100 * float(scene.rgb.masks.mean()):.1f} % of the pixels; smoke presence statistic "
              f"{decision.statistic:.2f} (threshold {decision.threshold}): "
              f"{'present' if decision.present else 'absent'}, dataset says present={scene.smoke_present}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    write_rows_csv(args.out / "smoke_presence.csv", presence)
    write_rows_csv(args.out / "smoke_masks.csv", rows)

    def mean_iou(cand: str, thr: float, split: str) -> float:
        return float(np.nanmean([r["iou"] for r in rows if r["candidate"] == cand and r["threshold"] == thr
                                 and r["split"] == split]))

    best = {c: max(THRESHOLDS, key=lambda t: mean_iou(c, float(t), "validation")) for c in ALL_CANDIDATES}
    chosen = max(ALL_CANDIDATES, key=lambda c: mean_iou(c, float(best[c]), "validation"))
    print("candidate, best validation threshold, validation IoU, test IoU (means over scenes)")
    for c in ALL_CANDIDATES:
        print(f"{c}, {best[c]}, {mean_iou(c, float(best[c]), 'validation'):.3f}, "
              f"{mean_iou(c, float(best[c]), 'test'):.3f}")
    print(f"{REFERENCE} (reference), -, {mean_iou(REFERENCE, 0.0, 'validation'):.3f}, "
          f"{mean_iou(REFERENCE, 0.0, 'test'):.3f}")
    print(f"chosen by validation: {chosen} at {best[chosen]}")
    per_scene = [r for r in rows if r["candidate"] == chosen and r["threshold"] == best[chosen]]
    write_rows_csv(args.out / "smoke_masks_choice.csv", per_scene)
    reference = {(r["scene"], r["split"]): r["iou"] for r in rows if r["candidate"] == REFERENCE}
    for r in per_scene:
        print(f"  {r['scene']:<12} {r['split']:<10} frames {r['frames']:>3}  IoU {r['iou']:.3f}  "
              f"(all-pixels {reference[(r['scene'], r['split'])]:.3f})")
    fig, ax = plt.subplots(figsize=(6, 4))
    for c in ALL_CANDIDATES:
        ax.plot(THRESHOLDS, [mean_iou(c, float(t), "validation") for t in THRESHOLDS], label=c)
    ax.axhline(mean_iou(REFERENCE, 0.0, "validation"), color="k", linestyle="--", label="all pixels smoke")
    ax.set_xlabel("threshold")
    ax.set_ylabel("mean validation IoU")
    ax.set_title(f"smoke masks without weights ({len(args.datasets)} scenes)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out / "smoke_masks.png", dpi=120)


if __name__ == "__main__":
    main()
