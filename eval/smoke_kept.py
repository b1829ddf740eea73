"""How much of the smoke's change to the frame stays in a de-smoked surface: a flame, a plume core.

A de-smoked render should show the scene as the clean frame does. Where the smoke changes a pixel
strongly (a flame's glow, the core of a plume), whatever of that change the surface render still
shows is smoke left in the surface. Per test view, the pixels whose colour the smoky frame moves by
more than ``CHANGE_EDGE`` in some channel from the clean frame (``d`` = smoky − clean) are the
strong-smoke pixels; the share of their change that the surface keeps is its error projected on
the smoke's change,

    kept = Σ (surface − clean) · d / Σ |d|²   over those pixels,

1 where the surface shows the smoky frame, 0 where it shows the clean frame, whatever the colour
of the smoke: a red flame changes a pixel's hue more than its brightness. It is the surface issue's
fire check as a number; the figure of every test view beside it (``write_fire_figure``) is the
check a reader can see.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from contracts.imageio import write_png
from eval.regions import CHANGE_EDGES, CLEAN, SMOKY, frames_at_render, surface_renders

CHANGE_EDGE = CHANGE_EDGES[-2]
"""Change (0-1, largest channel) the smoke must make to a pixel for it to count: 0.1, where the
region split's two strongest bands begin, well above the renders' noise and a shadow's darkening."""


@dataclass(frozen=True)
class SmokeKept:
    """One run's strong-smoke pixels over its test views and the share of their change it keeps."""

    views: int
    strong_pixels: int
    strong_share: float
    kept: float
    """nan where the views have no strong-smoke pixel: nothing to keep."""


def change_kept(smoky: np.ndarray, clean: np.ndarray, surface: np.ndarray) -> tuple[float, float, int]:
    """(Σ (surface − clean) · d, Σ |d|², strong pixels) of one view, each image H×W×3 in [0, 1]."""
    d = smoky - clean
    strong = np.abs(d).max(-1) > CHANGE_EDGE
    return (float(((surface - clean) * d)[strong].sum()), float((d * d)[strong].sum()), int(strong.sum()))


def run_kept(run_dir: Path, dataset: Path) -> tuple[SmokeKept, list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]]:
    """The run's ``SmokeKept`` over its saved surface renders (renders/surface/STEM.png) against
    the dataset's frames of the same stems, downscaled to the render's size by a whole factor, and
    the (stem, smoky, clean, surface) images it read. DatasetError names a missing file or a size
    that does not match."""
    renders = surface_renders(Path(run_dir))
    kept = change = 0.0
    strong = total = 0
    views = []
    for render in renders:
        surface, clean, smoky = frames_at_render(render, dataset, CLEAN, SMOKY)
        k, c, n = change_kept(smoky, clean, surface)
        kept, change, strong, total = kept + k, change + c, strong + n, total + surface.shape[0] * surface.shape[1]
        views.append((render.stem, smoky, clean, surface))
    return SmokeKept(len(renders), strong, strong / total, kept / change if change > 0 else math.nan), views


def write_fire_figure(path: Path, columns: list[str], views: dict[str, list[np.ndarray]]) -> None:
    """One row per test view (``views``: stem → images), one column per ``columns`` entry under
    its name, each image H×W×3 in [0, 1] at one size; a thin white rule between images. Written
    atomically."""
    rows = []
    for images in views.values():
        if len(images) != len(columns):
            raise ValueError(f"{path}: {len(images)} images for {len(columns)} columns")
        h = images[0].shape[0]
        rule = np.ones((h, 2, 3))
        cells = [x for img in images for x in (img, rule)][:-1]
        rows.append(np.concatenate(cells, axis=1))
    width = next(iter(views.values()))[0].shape[1]
    header = Image.new("RGB", (rows[0].shape[1], 14), "white")
    draw = ImageDraw.Draw(header)
    for i, name in enumerate(columns):
        draw.text((i * (width + 2) + 2, 1), name, fill="black")
    rule = np.ones((2, rows[0].shape[1], 3))
    grid = np.concatenate([np.asarray(header) / 255.0] + [x for row in rows for x in (rule, row)], axis=0)
    write_png(path, (np.clip(grid, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
