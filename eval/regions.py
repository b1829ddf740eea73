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

The third split is by reach: "unrecoverable" pixels are those whose surface no training view sees
with smoke alpha under 0.1 (contracts/unrecoverable.py; a dataset with RGB depth and smoke
opacity), "recoverable" the rest. No method can recover the first from RGB alone, so a method's
error there says what its thermal input or its priors bring.

Where the dataset has the shadowed ground truth (``rgb.shadowed``: the frames under the smoke's
shadow, no smoke in view), every region is scored against it too: on clear pixels the smoky input
against clean is off by the shadow, against shadowed only by render noise.

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
from contracts.dataset_format import PASS_FILES, PassFile, file_path, transforms_name
from contracts.errors import DatasetError
from contracts.imageio import image01, read_png
from contracts.metrics import PSNR_CAP_DB
from contracts.unrecoverable import dataset_unrecoverable
from eval.runs import RunResult, variant_label
from scenes.images import box_downscale

log = logging.getLogger(__name__)

REGIONS = ("smoky", "clear")
REACH = ("unrecoverable", "recoverable")
WHOLE = "all"
CHANGE_EDGES = (0.0, 0.02, 0.05, 0.1, 0.2)
"""Lower edges of the |smoky - clean| bands; the last band is open."""
BANDS = tuple(f"change {lo:g}-{hi:g}" for lo, hi in zip(CHANGE_EDGES, CHANGE_EDGES[1:])) + (f"change {CHANGE_EDGES[-1]:g}+",)
CLEAN, SMOKY = PASS_FILES[("rgb", "clean")][0], PASS_FILES[("rgb", "smoky")][0]
SHADOWED = PASS_FILES[("rgb", "shadowed")][0]
DEPTH, ALPHA, MASK = PASS_FILES[("rgb", "depth")][0], *PASS_FILES[("rgb", "smoke_alpha")]


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
    psnr_shadowed: float = math.nan  # the method against the shadowed frames (NaN without them)
    psnr_input_shadowed: float = math.nan  # the smoky input against the shadowed frames


def pooled_psnr(sq_error_sum: float, count: int) -> float:
    """PSNR of a pooled mean squared error on [0, 1] images, capped as contracts.metrics caps it;
    NaN for an empty region."""
    if count == 0:
        return math.nan
    return 10.0 * math.log10(1.0 / max(sq_error_sum / count, 10 ** (-PSNR_CAP_DB / 10)))


def surface_renders(run_dir: Path) -> list[Path]:
    """A finished run's saved test-view surface renders (renders/surface/STEM.png), by stem;
    DatasetError where there is none."""
    renders = sorted((run_dir / "renders" / "surface").glob("*.png"))
    if not renders:
        raise DatasetError(f"{run_dir / 'renders' / 'surface'}: no surface renders")
    return renders


def frames_at_render(render: Path, dataset: Path, *passes: PassFile) -> list[np.ndarray]:
    """A saved render (renders/SUB/STEM.png) and the dataset's frames of its stem for ``passes``,
    all in [0, 1], each frame box-downscaled to the render's size by the whole factor the first
    pass's frame is wider (a run trained at a reduced width). DatasetError names the render where a
    frame is not the render downscaled so, and a missing file."""
    pred = image01(read_png(render))
    frames = [image01(read_png(file_path(dataset, pf, render.stem))) for pf in passes]
    full = frames[0].shape
    factor = max(full[1] // pred.shape[1], 1)
    frames = [box_downscale(f, factor) for f in frames]
    if any(f.shape[:2] != pred.shape[:2] or f.shape[2:] not in ((), pred.shape[2:]) for f in frames):
        raise DatasetError(f"{render}: {pred.shape[1]}x{pred.shape[0]} render is not the dataset's frame {render.stem} "
                           f"({full[1]}x{full[0]}) downscaled by a whole factor")
    return [pred, *frames]


def score_run(result: RunResult, dataset: Path,
              unrecoverable: dict[str, np.ndarray] | None = None) -> list[RegionScore]:
    """The region split of one finished run: its saved surface renders (renders/surface/STEM.png)
    against the source dataset's clean frames (and shadowed frames, where it has them), with the
    smoky input and smoke mask of the same frames; with ``unrecoverable`` (masks by test frame at
    the dataset's resolution, ``dataset_unrecoverable``) the reach split too. ``dataset`` is the
    scene's original dataset (for the dehazing baseline too: the floor is the smoky input, not the
    dehazed one). DatasetError names a missing or unreadable file."""
    renders = surface_renders(Path(result.run_dir))
    shadowed = (Path(dataset) / SHADOWED.folder).is_dir()
    regions = (WHOLE,) + REGIONS + BANDS + (REACH if unrecoverable else ())
    # Per region: squared error of the method and of the input against clean, then against shadowed, and pixels.
    sums = {r: [0.0, 0.0, 0.0, 0.0, 0] for r in regions}
    for render in renders:
        pred, clean, smoky, mask, *rest = frames_at_render(render, dataset, CLEAN, SMOKY, MASK,
                                                           *((SHADOWED,) if shadowed else ()))
        mask = mask >= 0.5
        truth_sh = rest[0] if shadowed else clean
        errors = [((a - b) ** 2).sum(-1) for a, b in ((pred, clean), (smoky, clean), (pred, truth_sh),
                                                       (smoky, truth_sh))]
        band = np.searchsorted(CHANGE_EDGES, np.abs(smoky - clean).max(-1), side="right") - 1
        selections = [(WHOLE, np.ones_like(mask)), ("smoky", mask), ("clear", ~mask),
                      *((b, band == i) for i, b in enumerate(BANDS))]
        if unrecoverable:
            reach = unrecoverable[render.stem]  # at the dataset's resolution
            factor = reach.shape[1] // pred.shape[1]
            out_of_reach = box_downscale(reach[..., None].astype(np.float64), factor)[..., 0] >= 0.5
            selections += [("unrecoverable", out_of_reach), ("recoverable", ~out_of_reach)]
        for region, sel in selections:
            for j, err in enumerate(errors):
                sums[region][j] += float(err[sel].sum())
            sums[region][4] += int(sel.sum()) * 3
    total_pixels = sum(sums[r][4] for r in REGIONS)
    total_error = sum(sums[r][0] for r in REGIONS)

    def against_shadowed(err: float, count: int) -> float:
        return pooled_psnr(err, count) if shadowed else math.nan

    return [RegionScore(result.scene, result.variant, result.seed, region, len(renders),
                        count / total_pixels, pooled_psnr(err, count), pooled_psnr(err_in, count),
                        err / total_error if total_error > 0 else 0.0,
                        against_shadowed(err_sh, count), against_shadowed(err_in_sh, count))
            for region, (err, err_in, err_sh, err_in_sh, count) in sums.items()]


def reach_masks(dataset: Path) -> dict[str, np.ndarray]:
    """The unrecoverable mask of each test frame of ``dataset``; empty (no reach split) when it has
    no RGB transforms, depth or smoke opacity (hand-made test data, a real capture)."""
    root = Path(dataset)
    if not ((root / transforms_name("rgb")).is_file() and (root / DEPTH.folder).is_dir()
            and (root / ALPHA.folder).is_dir()):
        return {}
    return dataset_unrecoverable(root)


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
    lines += _reach_table(scores, keys) + _shadowed_table(scores, keys)
    if skipped:
        lines += ["", "Not split (said in the log too):", ""] + [f"- {s}" for s in skipped]
    return "\n".join(lines) + "\n"


def _rows(scores: list[RegionScore], scene: str, variant: str, region: str) -> list[RegionScore]:
    return [s for s in scores if (s.scene, s.variant, s.region) == (scene, variant, region)]


def _pair(rows: list[RegionScore], a: str, b: str) -> str:
    return f"{format_value(_mean(rows, a))} / {format_value(_mean(rows, b))}"


def _reach_table(scores: list[RegionScore], keys: list[tuple[str, str]]) -> list[str]:
    """The unrecoverable split, for the scenes whose datasets allow it."""
    keys = [k for k in keys if _rows(scores, *k, REACH[0])]
    if not keys:
        return []
    lines = ["", "## Out of reach of the RGB frames", "",
             "Unrecoverable pixels: no training view sees their surface with smoke alpha under 0.1 "
             "(docs/dataset-format.md, \"Statistics\"), so no method recovers them from RGB alone.", "",
             "| scene | method | seeds | unrecoverable pixels | unrecoverable: method / input (dB) "
             "| recoverable: method / input (dB) |", "|---|---|---|---|---|---|"]
    for scene, variant in keys:
        out, rest = _rows(scores, scene, variant, REACH[0]), _rows(scores, scene, variant, REACH[1])
        lines.append(f"| {scene} | {variant_label(variant)} | {len(out)} "
                     f"| {format_value(100 * _mean(out, 'pixel_share'), 0)} % | {_pair(out, 'psnr', 'psnr_input')} "
                     f"| {_pair(rest, 'psnr', 'psnr_input')} |")
    return lines


def _shadowed_table(scores: list[RegionScore], keys: list[tuple[str, str]]) -> list[str]:
    """Scores against clean and against shadowed, for the scenes whose datasets have shadowed."""
    keys = [k for k in keys if not math.isnan(_mean(_rows(scores, *k, WHOLE), "psnr_shadowed"))]
    if not keys:
        return []
    lines = ["", "## Against the shadowed ground truth", "",
             "`shadowed` is the scene under the smoke's shadow with no smoke in view: what a perfect "
             "de-smoker of the camera rays shows. On clear pixels the smoky input differs from it by "
             "render noise alone, from clean by the shadow too.", "",
             "| scene | method | seeds | method: vs clean / vs shadowed (dB) | input: vs clean / vs shadowed (dB) "
             "| clear pixels, input: vs clean / vs shadowed (dB) |", "|---|---|---|---|---|---|"]
    for scene, variant in keys:
        whole, clear = _rows(scores, scene, variant, WHOLE), _rows(scores, scene, variant, "clear")
        lines.append(f"| {scene} | {variant_label(variant)} | {len(whole)} | {_pair(whole, 'psnr', 'psnr_shadowed')} "
                     f"| {_pair(whole, 'psnr_input', 'psnr_input_shadowed')} "
                     f"| {_pair(clear, 'psnr_input', 'psnr_input_shadowed')} |")
    return lines


def _mean(scores: list[RegionScore], attr: str) -> float:
    """Mean over seeds, NaN (an empty region) left out."""
    return nan_mean([getattr(s, attr) for s in scores])


def write_region_split(results: list[RunResult], datasets: dict[str, Path], out_dir: Path) -> dict[str, Path]:
    """per_scene_regions.csv (one row per run and region) and per_scene_regions.md (the summary).
    A run whose scene has no smoke mask (a real capture) or whose files are missing is left out,
    with one log line and a line in the summary; a scene without depth and smoke opacity has no
    reach split, one without shadowed frames NaN for the scores against them."""
    scores: list[RegionScore] = []
    skipped: list[str] = []
    reach: dict[Path, dict[str, np.ndarray]] = {}  # one reprojection per dataset, however many runs
    for r in sorted((r for r in results if r.status == "ok"), key=lambda r: (r.scene, r.variant, r.seed)):
        dataset = datasets.get(r.scene)
        if dataset is None:
            skipped.append(f"{r.scene} {r.variant} seed {r.seed}: no dataset for the scene")
        elif not (Path(dataset) / MASK.folder).is_dir():
            skipped.append(f"{r.scene} {r.variant} seed {r.seed}: {Path(dataset) / MASK.folder} missing "
                           "(no smoke ground truth, e.g. a real capture)")
        else:
            try:
                if Path(dataset) not in reach:
                    reach[Path(dataset)] = reach_masks(Path(dataset))
                scores += score_run(r, Path(dataset), reach[Path(dataset)])
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
