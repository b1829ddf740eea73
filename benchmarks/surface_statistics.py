"""Is a de-smoked surface dark and flat? Brightness and contrast of finished runs' test renders.

    python benchmarks/surface_statistics.py LABEL=RUN_DIR [LABEL=RUN_DIR ...] --name NAME

For every test view of every run (its `renders/surface` and `renders/smoke` PNGs, written by
`train-and-evaluate` at the training resolution) it compares the surface render with the
smoke-free truth and the smoky input of the same view, loaded as the run loaded them (its
dataset and `max_width`): PSNR, mean luminance and luminance contrast (standard deviation over
the frame), and how well surface + smoke (the composite) explains the smoky input. A surface
much darker than the truth, with much less contrast, while the composite matches the input, is
what "dark and flat" means in numbers: the smoke layer took the image and left the surface
unconstrained. Writes benchmarks/results/NAME.csv and NAME.png (input, truth, surface, smoke per
row). Analysis only: it reads test renders and picks nothing.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from contracts.atomic import write_rows_csv  # noqa: E402
from contracts.metrics import psnr  # noqa: E402
from contracts.recorded_paths import recorded_location  # noqa: E402
from scenes.load import load_scene  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
LUMA = np.array([0.2126, 0.7152, 0.0722])


def _png(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / 255.0


def view_rows(label: str, run: Path) -> tuple[list[dict[str, object]], list[tuple[str, list[np.ndarray]]]]:
    """One row of statistics and one strip of images per test view of ``run``."""
    doc = json.loads((run / "metrics.json").read_text())
    cfg = json.loads((run / "config.json").read_text())
    scene = load_scene(recorded_location(doc["dataset"]), int(cfg.get("max_width", 0)), all_ground_truth=True)
    rgb = scene.rgb
    by_stem = {f.file_stem: i for i, f in enumerate(rgb.frames)}
    rows, strips = [], []
    for entry in doc["per_image"]:
        stem = entry["file_stem"]
        i = by_stem[stem]
        truth, smoky = rgb.clean[i].astype(np.float64), rgb.images[i].astype(np.float64)
        surface = _png(run / "renders" / "surface" / f"{stem}.png")
        smoke = _png(run / "renders" / "smoke" / f"{stem}.png")
        composite = _png(run / "renders" / "composite" / f"{stem}.png")
        lum = {name: img @ LUMA for name, img in (("truth", truth), ("input", smoky), ("surface", surface))}
        rows.append({"label": label, "scene": doc["scene"], "method": doc["method"], "view": stem,
                     "psnr_surface": psnr(surface, truth), "psnr_input": psnr(smoky, truth),
                     "psnr_composite_vs_input": psnr(composite, smoky),
                     "luminance_truth": float(lum["truth"].mean()), "luminance_input": float(lum["input"].mean()),
                     "luminance_surface": float(lum["surface"].mean()),
                     "contrast_truth": float(lum["truth"].std()), "contrast_input": float(lum["input"].std()),
                     "contrast_surface": float(lum["surface"].std())})
        strips.append((f"{label} {doc['scene']} {stem}", [smoky, truth, surface, smoke]))
    return rows, strips


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="LABEL=RUN_DIR")
    ap.add_argument("--name", required=True, help="output file stem")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    rows, strips = [], []
    for item in args.runs:
        label, _, run = item.partition("=")
        if not run:
            raise SystemExit(f"{item}: expected LABEL=RUN_DIR")
        r, s = view_rows(label, Path(run))
        rows += r
        strips += s
    args.out.mkdir(parents=True, exist_ok=True)
    write_rows_csv(args.out / f"{args.name}.csv", rows)
    for r in rows:
        print(f"{r['label']:<22} {r['scene']:<11} {r['view']:<8} surface {r['psnr_surface']:5.2f} dB "
              f"(input {r['psnr_input']:5.2f}); luminance truth/input/surface {r['luminance_truth']:.2f}/"
              f"{r['luminance_input']:.2f}/{r['luminance_surface']:.2f}; contrast {r['contrast_truth']:.3f}/"
              f"{r['contrast_input']:.3f}/{r['contrast_surface']:.3f}; composite vs input "
              f"{r['psnr_composite_vs_input']:.2f} dB")
    fig, axes = plt.subplots(len(strips), 4, figsize=(8, 1.6 * len(strips)), squeeze=False)
    for row, (row_axes, (title, images)) in enumerate(zip(axes, strips)):
        for ax, img, col in zip(row_axes, images, ("smoky input", "clean truth", "surface", "smoke layer")):
            ax.imshow(np.clip(img, 0.0, 1.0))
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(col, fontsize=8)
        row_axes[0].set_ylabel(title, fontsize=6)
    fig.tight_layout()
    fig.savefig(args.out / f"{args.name}.png", dpi=120)
    print(f"wrote {args.out / args.name}.csv and .png")


if __name__ == "__main__":
    main()
