"""Figures: test PSNR against wall-clock time, and qualitative grids like the paper's
Figures 3 (methods) and 5 (ablations), built from the runs' saved renders."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

from contracts.train_log import read_train_log  # noqa: E402
from eval.runs import VARIANTS, RunResult, variant_label  # noqa: E402

INPUT_COLUMNS = {"thermal": "Thermal input", "rgb": "RGB input", "gt": "Ground truth"}


def read_psnr_curve(result: RunResult) -> list[tuple[int, float, float, str]]:
    """(iteration, wall seconds, test PSNR, source) points of one run.

    Points come from train_log.csv rows with a test_psnr; the run's final PSNR is added
    at its total wall time. Dehazing time (prep_time_s) is added to every point, since
    the baseline pays it before training.
    """
    pts: list[tuple[int, float, float, str]] = []
    log = Path(result.run_dir) / "train_log.csv"
    if log.is_file():
        for row in read_train_log(log):
            v = (row.get("test_psnr") or "").strip()
            if v:
                pts.append((int(float(row["iteration"])), float(row["wall_s"]) + result.prep_time_s,
                            float(v), "train_log"))
    final = result.metrics.get("psnr")
    if final is not None:
        total = result.wall_time_s
        last_it = pts[-1][0] if pts else -1
        pts.append((last_it, float(total) + result.prep_time_s, float(final), "final"))
    return pts


PANELS_PER_ROW = 5
"""Scenes per row of the PSNR-time figure: ten scenes in one row would be too narrow to read."""


def write_psnr_vs_time(results: list[RunResult], out_dir: Path) -> tuple[Path, Path]:
    """psnr_vs_time.csv (every point) and .png (one panel per scene, one colour per method)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    ok = [r for r in results if r.status == "ok"]
    csv_path, png_path = out_dir / "psnr_vs_time.csv", out_dir / "psnr_vs_time.png"
    curves = {(r.scene, r.variant, r.seed): read_psnr_curve(r) for r in ok}
    with open(csv_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", "variant", "seed", "iteration", "wall_s", "test_psnr", "source"])
        for (scene, variant, seed), pts in sorted(curves.items()):
            for it, t, p, src in pts:
                w.writerow([scene, variant, seed, it, f"{t:.3f}", f"{p:.4f}", src])
    scenes = sorted({r.scene for r in results}) or ["(no runs)"]
    variants = sorted({r.variant for r in ok})
    methods_only = [v for v in variants if v in VARIANTS and VARIANTS[v].table == "methods"]
    shown = set(methods_only or variants)  # ablations stay in the CSV; the plot compares methods
    colours = {v: plt.cm.tab10(i % 10) for i, v in enumerate(variants)}
    cols = min(len(scenes), PANELS_PER_ROW)
    rows = -(-len(scenes) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.flat[len(scenes):]:
        ax.set_visible(False)
    for ax, scene in zip(axes.flat, scenes):
        labelled: set[str] = set()
        for (s, variant, seed), pts in sorted(curves.items()):
            if s != scene or not pts or variant not in shown:
                continue
            t = [p[1] for p in pts]
            y = [p[2] for p in pts]
            label = variant_label(variant)
            ax.plot(t, y, "-", color=colours[variant], alpha=0.85,
                    label=None if variant in labelled else label)
            labelled.add(variant)
            ax.plot(t[-1], y[-1], "o", color=colours[variant])
        ax.set_title(scene)
        ax.set_xlabel("wall-clock seconds")
        ax.set_ylabel("test PSNR (dB)")
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "no finished runs", ha="center", va="center", transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(png_path, dpi=120)
    plt.close(fig)
    return csv_path, png_path


def pick_test_frame(dataset: Path) -> dict:
    """The middle test view of the RGB camera (a fixed, reproducible choice)."""
    frames = json.loads((Path(dataset) / "transforms_rgb.json").read_text())["frames"]
    test = [f for f in frames if f.get("split") == "test"] or frames
    if not test:
        raise ValueError(f"dataset: {dataset} has no RGB frames")
    return test[len(test) // 2]


def _load_rgb(path: Path) -> np.ndarray | None:
    if not path.is_file():
        return None
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / 255.0


def _load_thermal(dataset: Path, time: float) -> np.ndarray | None:
    """The thermal frame nearest in time, contrast-stretched (1st-99th percentile) for display."""
    tf = Path(dataset) / "transforms_thermal.json"
    if not tf.is_file():
        return None
    frames = json.loads(tf.read_text())["frames"]
    if not frames:
        return None
    near = min(frames, key=lambda f: abs(float(f["time"]) - time))
    path = Path(dataset) / "thermal" / "smoky" / f"{near['file_stem']}.png"
    if not path.is_file():
        return None
    img = np.asarray(Image.open(path), dtype=np.float64)
    lo, hi = np.percentile(img, [1, 99])
    return np.clip((img - lo) / max(hi - lo, 1e-9), 0, 1)


def write_qualitative_grid(results: list[RunResult], datasets: dict[str, Path], columns: list[str],
                           out_path: Path, title: str) -> Path:
    """Rows = scenes; columns = inputs ("thermal", "rgb", "gt") and variant keys, whose
    panels are the surface-only render (the de-smoked prediction) of the lowest seed."""
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    scenes = sorted(datasets)
    fig, axes = plt.subplots(max(1, len(scenes)), len(columns), figsize=(2.3 * len(columns), 2.0 * max(1, len(scenes))),
                             squeeze=False)
    for i, scene in enumerate(scenes):
        frame = pick_test_frame(datasets[scene])
        stem = frame["file_stem"]
        for j, col in enumerate(columns):
            ax = axes[i][j]
            ax.set_xticks([])
            ax.set_yticks([])
            img, cmap, why = None, None, "missing"
            if col == "thermal":
                img, cmap = _load_thermal(datasets[scene], float(frame.get("time", 0.0))), "inferno"
            elif col == "rgb":
                img = _load_rgb(Path(datasets[scene]) / "rgb" / "smoky" / f"{stem}.png")
            elif col == "gt":
                img = _load_rgb(Path(datasets[scene]) / "rgb" / "clean" / f"{stem}.png")
            else:
                mine = sorted((r for r in results if r.scene == scene and r.variant == col), key=lambda r: r.seed)
                ok = [r for r in mine if r.status == "ok"]
                if ok:
                    img = _load_rgb(Path(ok[0].run_dir) / "renders" / "surface" / f"{stem}.png")
                elif mine:
                    why = "not trained yet" if all(r.status == "pending" for r in mine) else "run failed"
            if img is None:
                ax.set_facecolor("0.8")
                ax.text(0.5, 0.5, why, ha="center", va="center", transform=ax.transAxes, fontsize=8)
            else:
                ax.imshow(img, cmap=cmap, vmin=0, vmax=1, interpolation="nearest")
            if i == 0:
                ax.set_title(INPUT_COLUMNS.get(col) or variant_label(col), fontsize=8)
            if j == 0:
                ax.set_ylabel(f"{scene}\nframe {stem}", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(out_path, dpi=120)
    plt.close(fig)
    return out_path
