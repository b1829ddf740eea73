"""One figure per test view, so a run's result reads at a glance: what the RGB camera saw
through the smoke, what the thermal camera saw at that moment, the de-smoked render, and the
clean truth, side by side. Panels come from the arrays the run scored, not from re-read PNGs."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from contracts.atomic import atomic_path
from scenes.scene import ModalityData, SceneData
from smokeseer.evaluation.scoring import TestRenders

FIGURE_DIR = "figures"
PANEL_INCHES = 2.6
DPI = 100
"""Each panel is PANEL_INCHES × DPI pixels wide: a 64-pixel demo view is magnified about 4×."""


def figure_path(out: Path, stem: str) -> Path:
    """figures/test_view_NNNN.png, NNNN the test frame's file_stem."""
    return Path(out) / FIGURE_DIR / f"test_view_{stem}.png"


def nearest_thermal(thermal: ModalityData | None, time: float) -> np.ndarray | None:
    """The thermal input frame closest in normalised time, as the trainer reads it ([0, 1])."""
    if thermal is None or not thermal.frames:
        return None
    j = min(range(len(thermal.frames)), key=lambda k: abs(thermal.frames[k].time - time))
    return thermal.images[j][..., 0]


def _db(entry: dict[str, Any], key: str) -> str:
    value = entry.get(key)
    return f", {value:.1f} dB" if isinstance(value, float) else ""


def write_test_figures(renders: TestRenders, scene: SceneData, out: Path, per_image: list[dict[str, Any]],
                       method: str, thermal_used: bool) -> list[Path]:
    """figures/test_view_NNNN.png for every test view; PSNR against the clean truth in the
    panel titles where the data has it."""
    idx = scene.rgb.indices("test")
    scores = {e["file_stem"]: e for e in per_image}
    written = []
    for k, i in enumerate(idx):
        stem = renders.stems[k]
        entry = scores.get(stem, {})
        thermal = nearest_thermal(scene.thermal, scene.rgb.frames[i].time)
        clean = scene.rgb.clean[i] if scene.rgb.clean is not None else None
        panels = [
            (f"smoky RGB input{_db(entry, 'psnr_input')}", scene.rgb.images[i], None),
            ("thermal input" if thermal_used else "thermal (not used by this run)", thermal, "inferno"),
            (f"de-smoked render{_db(entry, 'psnr')}", renders.surface[k], None),
            ("clean truth", clean, None),
        ]
        fig = Figure(figsize=(PANEL_INCHES * len(panels), PANEL_INCHES * 0.75 + 0.7))
        FigureCanvasAgg(fig)
        axes = fig.subplots(1, len(panels))
        for ax, (title, image, cmap) in zip(axes, panels):
            ax.set_title(title, fontsize=9)
            if image is None:
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_facecolor("0.8")
                ax.text(0.5, 0.5, "not in this dataset", ha="center", va="center", transform=ax.transAxes,
                        fontsize=8)
                continue
            ax.imshow(np.clip(image, 0.0, 1.0), cmap=cmap, vmin=0.0, vmax=1.0, interpolation="nearest")
            ax.axis("off")
        fig.suptitle(f"{scene.name}, test view {stem}: {method}", fontsize=10)
        fig.tight_layout()
        path = figure_path(out, stem)
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=DPI)
        written.append(path)
    return written
