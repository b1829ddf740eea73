"""Where a method's error is: test-view PSNR split by the dataset's smoke mask, and by how much
the smoke changes each pixel.

Table 1 compares each method's surface render with the smoky input as a floor. On a scene with
thin or local smoke most pixels are smoke-free, the input is exact there, and a method loses to
it by its reconstruction error alone, whatever it does with the smoke. This split separates the
two: "smoky" pixels (the true RGB smoke mask of the test frame is set) measure de-smoking, "clear"
pixels measure reconstruction. Squared errors are pooled over a run's test views, per region,
so a region that is small in one view and large in another is weighed by its pixels.

The mask marks any smoke, however thin. The second split bands pixels by |smoky - clean| (the
largest channel): where the smoke changes a pixel by under 0.02 the input is nearly exact and a
method can only lose there; where it changes it by over 0.2 the input is far off and de-smoking
pays. Per band, the PSNRs say from which smoke strength on a method beats doing nothing.

The renders are the run's 8-bit PNGs, so whole-image PSNRs here can differ from metrics.json's
(scored on float renders) by the rounding. A run trained at a reduced width is compared with the
dataset's frames box-downscaled by the same whole factor as the trainer's loader does, and a pixel
counts as smoky when most of its block is.
"""

from __future__ import annotations

import csv
import logging
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from contracts.atomic import atomic_path, write_text
from contracts.dataset_format import PASS_FILES, file_path
from contracts.errors import DatasetError
from contracts.imageio import image01, read_png
from contracts.metrics import PSNR_CAP_DB
from eval.runs import RunResult, variant_label
from scenes.images import box_downscale

log = logging.getLogger(__name__)

REGIONS = ("smoky", "clear")
CHANGE_EDGES = (0.0, 0.02, 0.05, 0.1, 0.2)
"""Lower edges of the |smoky - clean| bands; the last band is open."""
BANDS = tuple(f"change {lo:g}-{hi:g}" for lo, hi in zip(CHANGE_EDGES, CHANGE_EDGES[1:])) + (f"change {CHANGE_EDGES[-1]:g}+",)
CLEAN, SMOKY = PASS_FILES[("rgb", "clean")][0], PASS_FILES[("rgb", "smoky")][0]
MASK = PASS_FILES[("rgb", "smoke_alpha")][1]


@dataclass(frozen=True)
class RegionScore:
    """One run's test views pooled over one region (a row of per_scene_regions.csv)."""

    scene: str
    variant: str
    seed: int
    region: str
    views: int
    pixel_share: float  # of all test-view pixels
    psnr: float  # the method's surface render against the clean frames, pooled squared error
    psnr_input: float  # the smoky input against the clean frames, same pixels
    error_share: float  # share of the method's squared error over all test pixels in this region


def pooled_psnr(sq_error_sum: float, count: int) -> float:
    """PSNR of a pooled mean squared error on [0, 1] images, capped as contracts.metrics caps it;
    NaN for an empty region."""
    if count == 0:
        return math.nan
    return 10.0 * math.log10(1.0 / max(sq_error_sum / count, 10 ** (-PSNR_CAP_DB / 10)))


def score_run(result: RunResult, dataset: Path) -> list[RegionScore]:
    """The region split of one finished run: its saved surface renders (renders/surface/STEM.png)
    against the source dataset's clean frames, with the smoky input and smoke mask of the same
    frames. ``dataset`` is the scene's original dataset (for the dehazing baseline too: the floor
    is the smoky input, not the dehazed one). DatasetError names a missing or unreadable file."""
    renders = sorted((Path(result.run_dir) / "renders" / "surface").glob("*.png"))
    if not renders:
        raise DatasetError(f"{Path(result.run_dir) / 'renders' / 'surface'}: no surface renders")
    sums = {r: [0.0, 0.0, 0] for r in REGIONS + BANDS}  # method sq error, input sq error, pixels
    for render in renders:
        stem = render.stem
        pred = image01(read_png(render))
        clean = image01(read_png(file_path(dataset, CLEAN, stem)))
        factor = clean.shape[1] // pred.shape[1]
        smoky = box_downscale(image01(read_png(file_path(dataset, SMOKY, stem))), factor)
        mask = box_downscale(image01(read_png(file_path(dataset, MASK, stem))), factor) >= 0.5
        clean = box_downscale(clean, factor)
        if not (pred.shape == clean.shape == smoky.shape and mask.shape == clean.shape[:2]):
            raise DatasetError(f"{render}: {pred.shape[1]}x{pred.shape[0]} render is not the dataset's frame {stem} "
                               f"({clean.shape[1] * factor}x{clean.shape[0] * factor}) downscaled by a whole factor")
        err = ((pred - clean) ** 2).sum(-1)
        err_in = ((smoky - clean) ** 2).sum(-1)
        band = np.searchsorted(CHANGE_EDGES, np.abs(smoky - clean).max(-1), side="right") - 1
        for region, sel in (("smoky", mask), ("clear", ~mask), *((b, band == i) for i, b in enumerate(BANDS))):
            sums[region][0] += float(err[sel].sum())
            sums[region][1] += float(err_in[sel].sum())
            sums[region][2] += int(sel.sum()) * 3
    total_pixels = sum(sums[r][2] for r in REGIONS)
    total_error = sum(sums[r][0] for r in REGIONS)
    return [RegionScore(result.scene, result.variant, result.seed, region, len(renders),
                        count / total_pixels, pooled_psnr(err, count), pooled_psnr(err_in, count),
                        err / total_error if total_error > 0 else 0.0)
            for region, (err, err_in, count) in sums.items()]


def nan_mean(values: list[float]) -> float:
    """Mean with NaN (an empty region, a missing record) left out; NaN when nothing is left."""
    vals = [v for v in values if not math.isnan(v)]
    return sum(vals) / len(vals) if vals else math.nan


def format_value(x: float, digits: int = 2) -> str:
    """A table cell: the number at ``digits`` decimals, "-" for NaN (an empty region or no view)."""
    return "-" if math.isnan(x) else f"{x:.{digits}f}"


def _summary(scores: list[RegionScore], skipped: list[str]) -> str:
    """Markdown: per scene and method, mean over seeds of each region's PSNR beside the input's."""
    lines = ["# Where the error is: test PSNR on smoky and on clear pixels", "",
             "Pixels split by the dataset's RGB smoke mask of each test frame; squared error pooled over "
             "a run's test views, then the mean over seeds. `clear` is reconstruction (the input is exact "
             "there up to the renderer's noise), `smoky` is de-smoking. Error share: the part of the "
             "method's squared error that lies on clear pixels.", "",
             "| scene | method | seeds | smoky pixels | smoky: method / input (dB) | clear: method / input (dB) "
             "| error share on clear |", "|---|---|---|---|---|---|---|"]
    keys = sorted({(s.scene, s.variant) for s in scores})
    for scene, variant in keys:
        mine = {r: [s for s in scores if (s.scene, s.variant, s.region) == (scene, variant, r)] for r in REGIONS}

        def mean(region: str, attr: str) -> float:
            return _mean(mine[region], attr)

        label = variant_label(variant)
        lines.append(f"| {scene} | {label} | {len(mine['smoky'])} "
                     f"| {format_value(100 * mean('smoky', 'pixel_share'), 0)} % "
                     f"| {format_value(mean('smoky', 'psnr'))} / {format_value(mean('smoky', 'psnr_input'))} "
                     f"| {format_value(mean('clear', 'psnr'))} / {format_value(mean('clear', 'psnr_input'))} "
                     f"| {format_value(100 * mean('clear', 'error_share'), 0)} % |")
    lines += ["", "## By how much the smoke changes a pixel", "",
              "Pixels banded by |smoky - clean| (largest channel) in each test frame; per band the method's "
              "PSNR / the input's, and the band's share of the test pixels. A method beats doing nothing "
              "only in the bands where its PSNR is the higher.", "",
              "| scene | method | seeds | " + " | ".join(BANDS) + " |", "|---|---|---|" + "---|" * len(BANDS)]
    for scene, variant in keys:
        mine = {b: [s for s in scores if (s.scene, s.variant, s.region) == (scene, variant, b)] for b in BANDS}
        label = variant_label(variant)
        cells = [f"{format_value(_mean(mine[b], 'psnr'), 1)} / {format_value(_mean(mine[b], 'psnr_input'), 1)} "
                 f"({format_value(100 * _mean(mine[b], 'pixel_share'), 0)} %)" for b in BANDS]
        lines.append(f"| {scene} | {label} | {len(mine[BANDS[0]])} | " + " | ".join(cells) + " |")
    if skipped:
        lines += ["", "Not split (said in the log too):", ""] + [f"- {s}" for s in skipped]
    return "\n".join(lines) + "\n"


def _mean(scores: list[RegionScore], attr: str) -> float:
    """Mean over seeds, NaN (an empty region) left out."""
    return nan_mean([getattr(s, attr) for s in scores])


def write_region_split(results: list[RunResult], datasets: dict[str, Path], out_dir: Path) -> dict[str, Path]:
    """per_scene_regions.csv (one row per run and region) and per_scene_regions.md (the summary).
    A run whose scene has no smoke mask (a real capture) or whose files are missing is left out,
    with one log line and a line in the summary."""
    scores: list[RegionScore] = []
    skipped: list[str] = []
    for r in sorted((r for r in results if r.status == "ok"), key=lambda r: (r.scene, r.variant, r.seed)):
        dataset = datasets.get(r.scene)
        if dataset is None:
            skipped.append(f"{r.scene} {r.variant} seed {r.seed}: no dataset for the scene")
        elif not (Path(dataset) / MASK.folder).is_dir():
            skipped.append(f"{r.scene} {r.variant} seed {r.seed}: {Path(dataset) / MASK.folder} missing "
                           "(no smoke ground truth, e.g. a real capture)")
        else:
            try:
                scores += score_run(r, Path(dataset))
            except DatasetError as exc:
                skipped.append(f"{r.scene} {r.variant} seed {r.seed}: {exc}")
    return write_split_files(out_dir, "per_scene_regions", RegionScore, scores, _summary(scores, skipped), skipped)


def write_split_files(out_dir: Path, name: str, row_type: type, rows: list[Any], summary: str,
                      skipped: list[str]) -> dict[str, Path]:
    """NAME.csv (one row per dataclass in ``rows``, a header even when there is none) and NAME.md
    (``summary``), both atomic; each line of ``skipped`` goes to the log too."""
    for line in skipped:
        log.info("%s: skipped %s", name, line)
    out_dir = Path(out_dir)
    csv_path, md_path = out_dir / f"{name}.csv", out_dir / f"{name}.md"
    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=[f.name for f in fields(row_type)])
        writer.writeheader()
        writer.writerows(asdict(r) for r in rows)
    write_text(md_path, summary)
    return {f"{name}.csv": csv_path, f"{name}.md": md_path}
