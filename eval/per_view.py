"""Per test view: on which views each method beats the smoky input and the method under test,
and what the mean over views hides.

Table 1's PSNR, like the paper's, is the mean over a scene's test views of each view's PSNR. A
scene whose smoke drifts leaves some views nearly clear (the input scores 30+ dB there) and
others hidden; the mean of PSNRs weighs them alike, so a method that de-smokes the hidden views
but reconstructs the clear ones less sharply can lose on the mean while its total squared error
is the smaller. This split shows both: per scene and method, the mean of the views' PSNRs, the
pooled PSNR (of the views' mean squared error), and the views won against the input and against
Full at the same seed and view, and each view's LPIPS beside its PSNR. Numbers come from each
run's metrics.json ``per_image``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from contracts.results_format import ResultsFormatError, read_metrics
from eval.regions import format_value, nan_mean, pooled_psnr, write_split_files
from eval.runs import VARIANTS, RunResult, variant_label
from eval.tables import RESCORED_LPIPS, rescored_lpips_note

REFERENCE = "full"
"""The method the others are counted against, view by view."""


@dataclass(frozen=True)
class ViewScore:
    """One test view of one run (a row of per_view.csv). ``psnr_input`` is the smoky input's,
    also for a dehazing baseline (whose own metrics score its dehazed frames). ``lpips`` is None
    where the run's record has no LPIPS for the view (scored without weights)."""

    scene: str
    variant: str
    seed: int
    view: str
    psnr: float
    psnr_input: float
    lpips: float | None = None


def pooled_over_views(psnrs: list[float]) -> float:
    """PSNR of the mean of the views' squared errors, each recovered from its PSNR on [0, 1]
    images (capped and NaN-when-empty as eval.regions.pooled_psnr)."""
    return pooled_psnr(sum(10 ** (-p / 10) for p in psnrs), len(psnrs))


def view_scores(results: list[RunResult], skipped: list[str] | None = None) -> list[ViewScore]:
    """Every test view of every finished run. A dehazing baseline's input column is taken from a
    run of the same scene on the smoky frames (NaN when there is none). A run whose metrics.json
    cannot be read is left out and named in ``skipped``."""
    raw: list[tuple[RunResult, dict]] = []
    smoky_input: dict[tuple[str, str], float] = {}
    for r in sorted((r for r in results if r.status == "ok"), key=lambda r: (r.scene, r.variant, r.seed)):
        dehazed = r.variant in VARIANTS and VARIANTS[r.variant].dehazer is not None
        try:
            per_image = read_metrics(Path(r.run_dir)).get("per_image", [])
        except ResultsFormatError as exc:
            if skipped is not None:
                skipped.append(f"{r.scene} {r.variant} seed {r.seed}: {exc}")
            continue
        for entry in per_image:
            raw.append((r, entry))
            if not dehazed:
                smoky_input.setdefault((r.scene, entry["file_stem"]), float(entry["psnr_input"]))
    return [ViewScore(r.scene, r.variant, r.seed, e["file_stem"], float(e["psnr"]),
                      smoky_input.get((r.scene, e["file_stem"]), math.nan),
                      None if e.get("lpips") is None else float(e["lpips"])) for r, e in raw]


def mean_of_all(values: list[float | None]) -> float:
    """The mean, NaN where a value is missing or there is none: an LPIPS mean over some views or
    scenes only would be over other ones than the PSNR beside it."""
    return math.nan if not values or any(v is None or math.isnan(v) for v in values) else sum(values) / len(values)


@dataclass(frozen=True)
class MethodSummary:
    """One scene and method over its seeds: means over seeds of the two averages, and view
    counts summed over seeds."""

    seeds: int
    mean_of_views: float
    pooled: float
    input_mean_of_views: float
    input_pooled: float
    above_input: int
    views: int
    above_reference: int | None  # views where this method beats Full; None for Full or no pair
    paired_views: int  # views with a Full view of the same seed to compare with
    lpips: float  # mean over seeds of the mean over views; NaN where a view has none


def summarise(scores: list[ViewScore], scene: str, variant: str) -> MethodSummary:
    mine = [s for s in scores if (s.scene, s.variant) == (scene, variant)]
    seeds = sorted({s.seed for s in mine})
    by_seed = {seed: [s for s in mine if s.seed == seed] for seed in seeds}
    reference = {(s.seed, s.view): s.psnr for s in scores if (s.scene, s.variant) == (scene, REFERENCE)}
    paired = [s for s in mine if (s.seed, s.view) in reference]
    return MethodSummary(
        seeds=len(seeds),
        mean_of_views=nan_mean([nan_mean([s.psnr for s in v]) for v in by_seed.values()]),
        pooled=nan_mean([pooled_over_views([s.psnr for s in v]) for v in by_seed.values()]),
        input_mean_of_views=nan_mean([s.psnr_input for s in by_seed[seeds[0]]]),
        input_pooled=pooled_over_views([s.psnr_input for s in by_seed[seeds[0]]]),
        above_input=sum(s.psnr > s.psnr_input for s in mine),
        views=len(mine),
        above_reference=None if variant == REFERENCE or not paired
        else sum(s.psnr > reference[(s.seed, s.view)] for s in paired),
        paired_views=len(paired),
        lpips=mean_of_all([mean_of_all([s.lpips for s in v]) for v in by_seed.values()]))


def _summary(scores: list[ViewScore], skipped: list[str], lpips_note: str | None) -> str:
    lines = ["# Per test view: which views each method wins", "",
             "Per scene and method: the mean over test views of each view's PSNR (Table 1's measure), the "
             "pooled PSNR (of the views' mean squared error, which weighs the smokiest views most), the "
             "same two for the smoky input, and the views on which the method beats the smoky input and "
             f"beats {VARIANTS[REFERENCE].label} at the same seed (counts summed over seeds); then the mean "
             "over test views of each view's LPIPS (Table 1's measure; '-' where a view has none). Means "
             "over seeds.", "",
             "| scene | method | seeds | mean of views | pooled | input: mean of views / pooled "
             f"| views above input | views above {VARIANTS[REFERENCE].label} | LPIPS ↓ |",
             "|---|---|---|---|---|---|---|---|---|"]
    keys = sorted({(s.scene, s.variant) for s in scores})
    summaries = {k: summarise(scores, *k) for k in keys}
    for (scene, variant), m in summaries.items():
        label = variant_label(variant)
        versus = "-" if m.above_reference is None else f"{m.above_reference}/{m.paired_views}"
        lines.append(f"| {scene} | {label} | {m.seeds} | {format_value(m.mean_of_views)} "
                     f"| {format_value(m.pooled)} | {format_value(m.input_mean_of_views)} "
                     f"/ {format_value(m.input_pooled)} | {m.above_input}/{m.views} | {versus} "
                     f"| {format_value(m.lpips, 3)} |")
    lines += ["", "## Mean over scenes", "",
              "| method | scenes | mean of views | pooled | input: mean of views / pooled | LPIPS ↓ |",
              "|---|---|---|---|---|---|"]
    for variant in sorted({v for _, v in keys}):
        rows = [m for (_, v), m in summaries.items() if v == variant]
        label = variant_label(variant)
        cells = [format_value(nan_mean([getattr(m, attr) for m in rows]))
                 for attr in ("mean_of_views", "pooled", "input_mean_of_views", "input_pooled")]
        lines.append(f"| {label} | {len(rows)} | {cells[0]} | {cells[1]} | {cells[2]} / {cells[3]} "
                     f"| {format_value(mean_of_all([m.lpips for m in rows]), 3)} |")
    if lpips_note:
        lines += ["", f"- {lpips_note}"]
    if skipped:
        lines += ["", "Left out (said in the log too):", ""] + [f"- {s}" for s in skipped]
    return "\n".join(lines) + "\n"


def write_per_view(results: list[RunResult], out_dir: Path) -> dict[str, Path]:
    """per_view.csv (one row per run and test view) and per_view.md (the summary). A run whose
    metrics.json cannot be read is left out, with one log line and a line in the summary. Where
    runs' LPIPS was scored after training, the summary says so as Table 1 does."""
    skipped: list[str] = []
    scores = view_scores(results, skipped)
    statuses = [str(r.metrics.get("lpips_status", "")) for r in results if r.status == "ok"]
    rescored = [s for s in statuses if s.startswith(RESCORED_LPIPS)]
    note = rescored_lpips_note(rescored, len(rescored), len(statuses)) if rescored else None
    return write_split_files(out_dir, "per_view", ViewScore, scores, _summary(scores, skipped, note), skipped)
