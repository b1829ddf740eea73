"""`contact-sheet`: one PNG per dataset so that a person can look at the data.

Rows are three instants (first, middle and last RGB frame); columns are RGB with smoke,
RGB clean, thermal (sensor counts of the thermal frame nearest in time), the RGB smoke
mask and the RGB depth. Thermal shares one contrast stretch across the rows, and so does
depth, so that brightness changes between rows are real changes in the scene.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from contracts.dataset_format import PASS_FILES, file_path, transforms_name
from contracts.errors import DatasetError
from contracts.imageio import read_exr_channel, read_png
from generator.errors import GeneratorError

COLUMNS = ("RGB smoky", "RGB clean", "thermal smoky", "smoke mask", "depth")
STRETCH_PERCENTILES = (1.0, 99.0)


@dataclass(frozen=True)
class Row:
    """One instant: the RGB frame and the thermal frame nearest to it in normalised time."""

    time: float
    rgb_stem: str
    thermal_stem: str | None


def find_datasets(root: Path) -> list[Path]:
    """`root` itself when it is a dataset, else its immediate sub-folders that are datasets."""
    root = Path(root)
    if (root / "dataset.json").is_file():
        return [root]
    if not root.is_dir():
        raise DatasetError(f"{root}: no such folder")
    found = sorted(p for p in root.iterdir() if p.is_dir() and (p / "dataset.json").is_file())
    if not found:
        raise DatasetError(f"{root}: neither a dataset (no dataset.json) nor a folder of datasets")
    return found


def _frames(dataset: Path, modality: str) -> list[dict[str, Any]]:
    path = dataset / transforms_name(modality)
    return json.loads(path.read_text())["frames"] if path.is_file() else []


def pick_rows(dataset: Path) -> list[Row]:
    """First, middle and last RGB frames, each paired with the thermal frame closest in time."""
    rgb = _frames(dataset, "rgb")
    if not rgb:
        raise DatasetError(f"{dataset}: no RGB frames ({transforms_name('rgb')} missing or empty)")
    thermal = _frames(dataset, "thermal")
    picks = sorted({0, (len(rgb) - 1) // 2, len(rgb) - 1})
    rows = []
    for i in picks:
        t = float(rgb[i]["time"])
        nearest = min(thermal, key=lambda f: abs(float(f["time"]) - t)) if thermal else None
        rows.append(Row(t, rgb[i]["file_stem"], nearest["file_stem"] if nearest else None))
    return rows


def load_pass(dataset: Path, modality: str, pass_name: str, part: int, stem: str | None) -> np.ndarray | None:
    if stem is None:
        return None
    pf = PASS_FILES[(modality, pass_name)][part]
    path = file_path(dataset, pf, stem)
    if not path.is_file():
        return None
    return read_exr_channel(path, pf.exr_channel) if pf.exr_channel else read_png(path)


def stretch(images: list[np.ndarray], valid: list[np.ndarray] | None = None) -> tuple[float, float]:
    """Percentile limits over every (valid) pixel of the rows, never an empty range."""
    masks = valid if valid is not None else [np.ones(im.shape, dtype=bool) for im in images]
    values = np.concatenate([im[m].astype(np.float64) for im, m in zip(images, masks)] or [np.zeros(0)])
    if values.size == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(values, STRETCH_PERCENTILES)
    return float(lo), float(hi if hi > lo else lo + 1.0)


def _resize(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Bilinear upsampling of a float map to the RGB size, so the panels line up."""
    pil = Image.fromarray(image.astype(np.float32), mode="F").resize((width, height), Image.BILINEAR)
    return np.asarray(pil)


def thermal_panel(counts: np.ndarray, lo: float, hi: float, size: tuple[int, int]) -> np.ndarray:
    scaled = np.clip((counts.astype(np.float64) - lo) / (hi - lo), 0.0, 1.0)
    return colormaps["inferno"](_resize(scaled, *size))[..., :3]


def _depth_panel(depth: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Near is bright; sky (depth 0) is black."""
    scaled = np.clip((depth - lo) / (hi - lo), 0.0, 1.0)
    image = colormaps["turbo"](1.0 - scaled)[..., :3]
    image[depth <= 0] = 0.0
    return image


def _title(dataset: Path, meta: dict[str, Any]) -> str:
    smoke, stats = meta.get("smoke", {}), meta.get("stats", {})

    def fmt(key: str, spec: str) -> str:
        value = stats.get(key)
        return format(value, spec) if isinstance(value, (int, float)) else "n/a"

    flags = ", fire" if smoke.get("fire") else ""
    return (f"{dataset.name} (scene {meta.get('scene', '?')}): density {smoke.get('density', 'n/a')}{flags}; "
            f"RGB mean smoke alpha {fmt('rgb_mean_smoke_alpha', '.3f')}, smoke fraction "
            f"{fmt('rgb_smoke_fraction', '.2f')}, thermal mean alpha {fmt('thermal_mean_smoke_alpha', '.4f')}, "
            f"PSNR smoky vs clean {fmt('psnr_smoky_vs_clean', '.1f')} dB")


def make_contact_sheet(dataset: Path, out_png: Path, panel_inches: float = 2.4) -> Path:
    """Write the contact sheet of one dataset; absent passes show as an empty grey panel."""
    dataset = Path(dataset)
    meta_path = dataset / "dataset.json"
    if not meta_path.is_file():
        raise DatasetError(f"{dataset}: not a dataset (no dataset.json)")
    meta = json.loads(meta_path.read_text())
    rows = pick_rows(dataset)
    smoky = [load_pass(dataset, "rgb", "smoky", 0, r.rgb_stem) for r in rows]
    clean = [load_pass(dataset, "rgb", "clean", 0, r.rgb_stem) for r in rows]
    thermal = [load_pass(dataset, "thermal", "smoky", 1, r.thermal_stem) for r in rows]
    masks = [load_pass(dataset, "rgb", "smoke_alpha", 1, r.rgb_stem) for r in rows]
    depths = [load_pass(dataset, "rgb", "depth", 0, r.rgb_stem) for r in rows]
    reference = next((im for im in smoky + clean + depths + masks if im is not None), None)
    if reference is None:
        raise DatasetError(f"{dataset}: none of the RGB passes a contact sheet shows is present")
    height, width = reference.shape[:2]
    t_lo, t_hi = stretch([t for t in thermal if t is not None])
    present = [d for d in depths if d is not None]
    d_lo, d_hi = stretch(present, [d > 0 for d in present])
    blank = np.full((height, width, 3), 0.5)

    fig = Figure(figsize=(panel_inches * len(COLUMNS), panel_inches * height / width * len(rows) + 0.9))
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(rows), len(COLUMNS), squeeze=False)
    for r, row in enumerate(rows):
        panels = [
            smoky[r] / 255.0 if smoky[r] is not None else blank,
            clean[r] / 255.0 if clean[r] is not None else blank,
            thermal_panel(thermal[r], t_lo, t_hi, (width, height)) if thermal[r] is not None else blank,
            np.repeat((masks[r] / 255.0)[..., None], 3, axis=2) if masks[r] is not None else blank,
            _depth_panel(depths[r], d_lo, d_hi) if depths[r] is not None else blank,
        ]
        for c, panel in enumerate(panels):
            ax = axes[r][c]
            ax.imshow(panel, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(COLUMNS[c], fontsize=9)
        label = f"t={row.time:.2f}\nrgb {row.rgb_stem}"
        if row.thermal_stem is not None:
            label += f"\nthermal {row.thermal_stem}"
        axes[r][0].set_ylabel(label, fontsize=8)
    fig.suptitle(_title(dataset, meta), fontsize=8, wrap=True)
    fig.text(0.5, 0.005, f"thermal counts {t_lo:.0f}-{t_hi:.0f} (inferno); depth {d_lo:.1f}-{d_hi:.1f} m "
             "(turbo, near = red, sky = black)", ha="center", fontsize=7)
    fig.tight_layout(rect=(0, 0.02, 1, 0.95))
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    return out_png


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="contact-sheet", description=(
        "Write one PNG per dataset: RGB smoky, RGB clean, thermal, smoke mask and depth at the "
        "first, middle and last frame."))
    p.add_argument("datasets", type=Path, metavar="DATASET_OR_BENCH_DIR",
                   help="a dataset folder, or a folder of datasets (e.g. generate-benchmark's output)")
    p.add_argument("--out", type=Path, required=True, help="folder for the PNGs (one per dataset)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        for dataset in find_datasets(args.datasets):
            print(make_contact_sheet(dataset, args.out / f"{dataset.name}.png"))
    except (GeneratorError, DatasetError) as exc:
        print(f"contact-sheet: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
