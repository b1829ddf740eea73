"""Would more budget close a gap? The validation PSNR's slope over the end of each run.

Every run logs its validation PSNR every few hundred iterations of its last stage. A straight
line fitted to the points of the last TAIL_ITERATIONS iterations gives the rate at which the run
was still improving when the budget ran out. Per scene, Full's end value and rate beside another
method's (or the smoky input's, which does not move) say whether Full is catching up, and how many
more iterations a straight continuation of both rates would need to close the gap. That number is
a rough guide, not a bound: the curves flatten, but the rates were measured while the learning
rates decay towards the end of the budget, and a longer schedule decays them later. A run at a
larger budget measures it directly. Validation views only, never test views.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from contracts.results_format import ResultsFormatError, read_metrics
from contracts.train_log import read_train_log
from eval.regions import format_value, nan_mean, write_split_files
from eval.runs import RunResult, variant_label

TAIL_ITERATIONS = 1000
"""The slope is fitted over the validation points of the last this many iterations."""
REFERENCE = "full"


@dataclass(frozen=True)
class RunConvergence:
    """One run's end of training (a row of convergence.csv)."""

    scene: str
    variant: str
    seed: int
    stage: int
    last_iteration: int
    val_psnr_end: float
    slope_per_1000: float  # dB per 1000 iterations over the tail
    tail_points: int
    val_psnr_input: float  # the smoky input on the validation views (NaN when not recorded)


def _line_slope(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope; NaN with fewer than two distinct x."""
    n = len(xs)
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    return math.nan if sxx == 0 else sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx


def run_convergence(result: RunResult) -> RunConvergence:
    """The tail of one finished run's validation curve. ResultsFormatError when its folder has no
    train_log.csv or the log has no validation point."""
    log_path = Path(result.run_dir) / "train_log.csv"
    if not log_path.is_file():
        raise ResultsFormatError(f"{log_path}: missing")
    points = [(int(r["stage"]), int(float(r["iteration"])), float(r["val_psnr"]))
              for r in read_train_log(log_path) if (r.get("val_psnr") or "").strip()]
    if not points:
        raise ResultsFormatError(f"{log_path}: field val_psnr: no validation point")
    stage = points[-1][0]
    last = points[-1][1]
    tail = [(it, v) for s, it, v in points if s == stage and it >= last - TAIL_ITERATIONS]
    slope = _line_slope([it / 1000 for it, _ in tail], [v for _, v in tail])
    validation = read_metrics(Path(result.run_dir)).get("validation") or {}
    val_input = validation.get("psnr_input")
    return RunConvergence(result.scene, result.variant, result.seed, stage, last, points[-1][2], slope,
                          len(tail), math.nan if val_input is None else float(val_input))


def iterations_to_close(gap_db: float, closing_rate_per_1000: float) -> float:
    """Iterations a straight continuation needs to make up ``gap_db`` (behind when negative) at
    ``closing_rate_per_1000`` (how much faster the one behind improves). 0 when not behind, inf
    when it is not catching up."""
    if gap_db >= 0:
        return 0.0
    if not closing_rate_per_1000 > 0:
        return math.inf
    return -gap_db / closing_rate_per_1000 * 1000


def _closing_cell(gap: float, rate: float) -> str:
    if math.isnan(gap) or math.isnan(rate):
        return "-"
    its = iterations_to_close(gap, rate)
    return "ahead" if its == 0 else ("not closing" if math.isinf(its) else f"{its:,.0f}")


@dataclass(frozen=True)
class _SceneMeans:
    """One scene and method: means over its seeds, NaN where nothing was recorded."""

    seeds: int
    end: float
    slope: float
    val_input: float


def _scene_means(rows: list[RunConvergence]) -> dict[tuple[str, str], _SceneMeans]:
    by_key: dict[tuple[str, str], list[RunConvergence]] = {}
    for r in rows:
        by_key.setdefault((r.scene, r.variant), []).append(r)
    return {key: _SceneMeans(len(runs), nan_mean([r.val_psnr_end for r in runs]),
                             nan_mean([r.slope_per_1000 for r in runs]), nan_mean([r.val_psnr_input for r in runs]))
            for key, runs in by_key.items()}


def _summary(rows: list[RunConvergence], skipped: list[str]) -> str:
    lines = ["# Would more budget close the gap? (validation PSNR)", "",
             f"Per scene and method, means over seeds: the validation PSNR at the end of the run and its slope "
             f"over the last {TAIL_ITERATIONS} iterations (dB per 1000, a least-squares line through the "
             f"logged points). For {variant_label(REFERENCE)} against each other method and against the "
             "smoky input: the gap at the end (negative: behind) and the extra iterations a straight "
             "continuation of both slopes needs to close it (a rough guide: the curves flatten, but the "
             "slopes were measured under learning rates decaying to the budget's end).", "",
             "| scene | method | seeds | end (dB) | slope (dB/1000 it) | gap to " + variant_label(REFERENCE)
             + " | extra iterations for " + variant_label(REFERENCE) + " to catch up |",
             "|---|---|---|---|---|---|---|"]
    means = _scene_means(rows)
    for scene in sorted({s for s, _ in means}):
        ref = means.get((scene, REFERENCE))
        for variant in sorted({v for s, v in means if s == scene}, key=lambda v: (v != REFERENCE, v)):
            mine = means[(scene, variant)]
            versus = variant != REFERENCE and ref is not None
            gap = format_value(ref.end - mine.end) if versus else "-"
            closing = _closing_cell(ref.end - mine.end, ref.slope - mine.slope) if versus else "-"
            lines.append(f"| {scene} | {variant_label(variant)} | {mine.seeds} | {format_value(mine.end)} "
                         f"| {format_value(mine.slope)} | {gap} | {closing} |")
        if ref is not None and not math.isnan(ref.val_input):
            gap = ref.end - ref.val_input
            lines.append(f"| {scene} | smoky input | - | {format_value(ref.val_input)} | 0.00 "
                         f"| {format_value(gap)} | {_closing_cell(gap, ref.slope)} |")
    lines += _mean_over_scenes(means)
    if skipped:
        lines += ["", "Left out (said in the log too):", ""] + [f"- {s}" for s in skipped]
    return "\n".join(lines) + "\n"


def _mean_over_scenes(means: dict[tuple[str, str], _SceneMeans]) -> list[str]:
    """The same columns for the mean over the scenes that have both Full and the method: the gap
    of the tables' headline (a mean over scenes) and how fast it was closing."""
    lines = ["", "## Mean over scenes", "",
             "Each scene's means over seeds, then the mean over the scenes that have both runs.", "",
             "| method | scenes | end (dB) | slope (dB/1000 it) | " + variant_label(REFERENCE) + " end / slope "
             "| gap to " + variant_label(REFERENCE) + " | extra iterations for " + variant_label(REFERENCE)
             + " to catch up |", "|---|---|---|---|---|---|---|"]
    ref = {s: m for (s, v), m in means.items() if v == REFERENCE}
    others: list[tuple[str, dict[str, tuple[float, float]]]] = [
        (variant_label(variant), {s: (m.end, m.slope) for (s, v), m in means.items() if v == variant and s in ref})
        for variant in sorted({v for _, v in means} - {REFERENCE})]
    others.append(("smoky input", {s: (m.val_input, 0.0) for s, m in ref.items() if not math.isnan(m.val_input)}))
    for label, by_scene in others:
        if not by_scene:
            continue
        ref_end = nan_mean([ref[s].end for s in by_scene])
        ref_slope = nan_mean([ref[s].slope for s in by_scene])
        end, slope = nan_mean([e for e, _ in by_scene.values()]), nan_mean([k for _, k in by_scene.values()])
        lines.append(f"| {label} | {len(by_scene)} | {format_value(end)} | {format_value(slope)} "
                     f"| {format_value(ref_end)} / {format_value(ref_slope)} | {format_value(ref_end - end)} "
                     f"| {_closing_cell(ref_end - end, ref_slope - slope)} |")
    return lines


def write_convergence(results: list[RunResult], out_dir: Path) -> dict[str, Path]:
    """convergence.csv (one row per finished run) and convergence.md (the per-scene summary). A run
    whose log cannot be read is left out, with one log line and a line in the summary."""
    rows, skipped = [], []
    for r in sorted((r for r in results if r.status == "ok"), key=lambda r: (r.scene, r.variant, r.seed)):
        try:
            rows.append(run_convergence(r))
        except ResultsFormatError as exc:
            skipped.append(f"{r.scene} {r.variant} seed {r.seed}: {exc}")
    return write_split_files(out_dir, "convergence", RunConvergence, rows, _summary(rows, skipped), skipped)
