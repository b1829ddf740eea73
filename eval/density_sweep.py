"""The density sweep's arithmetic: how much smoke a scene's test views hold, Full's lead over
RGB-only per seed, and the optical depth at which that lead turns positive.

The sweep renders one bake per scene at smoke density scales k; a pixel's opacity is then
1 − (1 − α)^k, i.e. its optical depth τ = −ln(1 − α) scales by k. Its x axis is the mean optical
depth −ln(1 − ᾱ) of the RGB smoke over the test views' pixels.
"""
from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.dataset_format import PASS_FILES, file_path
from contracts.imageio import image01, read_exr_channel, read_png
from eval.claims import ClaimCheck, verdict
from eval.tables import Stat, format_stat


def stems_of_test_views(dataset: Path) -> list[str]:
    """The file stems of a dataset's RGB test views, as its transforms split them."""
    frames = json.loads((Path(dataset) / "transforms_rgb.json").read_text())["frames"]
    return [f["file_stem"] for f in frames if f["split"] == "test"]


def frames_of_test_views(dataset: Path) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Each RGB test view's smoky frame, clean frame (both in [0, 1]) and smoke opacity."""
    alpha_file = PASS_FILES[("rgb", "smoke_alpha")][0]
    for stem in stems_of_test_views(dataset):
        yield (image01(read_png(dataset / "rgb" / "smoky" / f"{stem}.png")),
               image01(read_png(dataset / "rgb" / "clean" / f"{stem}.png")),
               read_exr_channel(file_path(dataset, alpha_file, stem), "A"))


def mean_optical_depth(alphas: list[np.ndarray]) -> float:
    """−ln(1 − ᾱ), ᾱ the mean RGB smoke opacity over every pixel of the given views."""
    if not alphas:
        raise ValueError("mean_optical_depth: no views")
    mean = float(np.mean([float(np.mean(np.clip(a, 0.0, 1.0))) for a in alphas]))
    return -math.log1p(-min(mean, 1.0 - 1e-12))


def frame_at_scale(smoky: np.ndarray, clean: np.ndarray, alpha: np.ndarray, k: float,
                   alpha_min: float = 1e-3) -> np.ndarray:
    """An estimate of a smoky frame at density scale k from the same frame at k = 1, for choosing a
    ladder before rendering it. Per pixel, I = (1 − α)·J + α·A with J the clean frame and α the
    smoke opacity; the smoke's own colour A is solved for where α > ``alpha_min`` (clipped to
    [0, 1]) and held, while the opacity becomes 1 − (1 − α)^k. Where α ≤ ``alpha_min`` the k = 1
    frame is kept, render noise and all. It ignores how the smoke's colour changes with its
    density (self-shadowing, multiple scattering), so it is a guide, not a render."""
    if k < 0 or not math.isfinite(k):
        raise ValueError(f"frame_at_scale: k must be finite and at least 0, got {k!r}")
    a = np.clip(alpha, 0.0, 1.0 - 1e-9)
    if a.ndim == smoky.ndim - 1:  # one opacity per pixel, shared by the colour channels
        a = a[..., None]
    smoke = a > alpha_min
    colour = np.clip((smoky - (1.0 - a) * clean) / np.where(smoke, a, 1.0), 0.0, 1.0)
    a_k = 1.0 - (1.0 - a) ** k
    return np.where(smoke, (1.0 - a_k) * clean + a_k * colour, smoky)


@dataclass(frozen=True)
class Lead:
    """Full − RGB-only over the seeds both finished: mean and sample std of the per-seed
    differences (std None with one seed)."""

    mean: float
    std: float | None
    seeds: tuple[int, ...]


def paired_lead(full: dict[int, float], rgb_only: dict[int, float]) -> Lead | None:
    """The lead on the seeds both methods finished; None when they share none."""
    seeds = tuple(sorted(set(full) & set(rgb_only)))
    if not seeds:
        return None
    diffs = [full[s] - rgb_only[s] for s in seeds]
    mean = sum(diffs) / len(diffs)
    std = math.sqrt(sum((d - mean) ** 2 for d in diffs) / (len(diffs) - 1)) if len(diffs) > 1 else None
    return Lead(mean, std, seeds)


def crossover(depths: list[float], leads: list[float]) -> tuple[float | None, str]:
    """The optical depth at which the lead first turns from negative to non-negative, linearly
    interpolated between the two measured densities around it, and how it was found:
    "crossing", "ahead throughout" (never negative: None), "behind throughout" (never
    non-negative: None), "falls behind" (ahead at thin smoke, behind at dense: None) or
    "crossing, then behind again" when it falls back below zero later (the first crossing is
    returned)."""
    if len(depths) != len(leads) or not depths:
        raise ValueError("crossover: need one lead per optical depth, at least one")
    order = sorted(range(len(depths)), key=lambda i: depths[i])
    x = [depths[i] for i in order]
    y = [leads[i] for i in order]
    if all(v >= 0 for v in y):
        return None, "ahead throughout"
    if all(v < 0 for v in y):
        return None, "behind throughout"
    first = next((i for i in range(1, len(y)) if y[i - 1] < 0 <= y[i]), None)
    if first is None:
        return None, "falls behind"
    x0, x1, y0, y1 = x[first - 1], x[first], y[first - 1], y[first]
    at = x0 + (x1 - x0) * (-y0) / (y1 - y0)
    again = any(v < 0 for v in y[first:])
    return at, "crossing, then behind again" if again else "crossing"


@dataclass(frozen=True)
class SweepTargets:
    """The sweep's must-holds (issue 49), on test PSNR in dB, scene values the means over seeds."""

    scenes: int = 3
    densities: int = 5
    seeds: tuple[int, ...] = (0, 1, 2)
    clear_lag: float = 0.1
    """At k = 0 (no smoke), Full ≥ RGB-only − this on every scene."""
    dense_rgb_only: float = 16.0
    """The densest k of a scene must bring RGB-only to this or below (about the paper's regime)..."""
    dense_lead: float = 3.0
    """...where Full − RGB-only is at least this."""


def _leads(rows: list[dict], scene: str) -> list[dict]:
    """A scene's rows that have a lead, in order of k."""
    return sorted((r for r in rows if r["scene"] == scene and r["lead_psnr"] is not None), key=lambda r: r["k"])


def _seeds_text(rows: list[dict]) -> str:
    return "; ".join(f"{r['scene']} k {r['k']:g}: {r['full_seeds'] or '-'} / {r['rgb-only_seeds'] or '-'}" for r in rows)


def sweep_checks(rows: list[dict], targets: SweepTargets = SweepTargets()) -> list[ClaimCheck]:
    """The sweep's must-holds on its rows (benchmarks/density_sweep.py's sweep.csv): its coverage,
    no cost at k = 0, the lead at the densest k, and a lead that does not fall as k rises beyond
    the spread of the two leads over seeds, √(s₁² + s₂²)."""
    scenes = sorted({r["scene"] for r in rows})
    leads = {sc: _leads(rows, sc) for sc in scenes}
    want = " ".join(str(s) for s in targets.seeds)
    complete = {sc: [r["k"] for r in rows if r["scene"] == sc and r["full_seeds"] == want
                     and r["rgb-only_seeds"] == want] for sc in scenes}
    covered = [sc for sc in scenes if len(complete[sc]) >= targets.densities]
    checks = [ClaimCheck(
        f"≥ {targets.scenes} scenes × ≥ {targets.densities} densities × seeds {want}, Full and RGB-only",
        verdict(len(covered) >= targets.scenes),
        "; ".join(f"{sc}: {len(complete[sc])} complete (k {', '.join(f'{k:g}' for k in complete[sc]) or '-'})"
                  for sc in scenes), want, "")]

    clear = [r for sc in scenes for r in leads[sc] if r["k"] == 0]
    missing = [sc for sc in scenes if sc not in {r["scene"] for r in clear}]
    checks.append(ClaimCheck(
        f"k = 0: Full ≥ RGB-only − {targets.clear_lag:g} dB on every scene",
        verdict(False if any(r["lead_psnr"] < -targets.clear_lag for r in clear) else None if missing else True),
        ", ".join(f"{r['scene']} {r['lead_psnr']:+.2f}" for r in clear) or "-", _seeds_text(clear),
        ", ".join(missing)))

    dense, notes = [], []
    for sc in scenes:
        if not leads[sc]:
            continue
        top = leads[sc][-1]
        dense.append(top)
        reached = top["rgb-only_psnr"] <= targets.dense_rgb_only
        notes.append(f"{sc} k {top['k']:g}: RGB-only {top['rgb-only_psnr']:.2f} dB, lead {top['lead_psnr']:+.2f}"
                     + ("" if reached else f" (RGB-only above {targets.dense_rgb_only:g} dB: the sweep stops short)"))
    ok = None if not dense else all(r["rgb-only_psnr"] <= targets.dense_rgb_only
                                    and r["lead_psnr"] >= targets.dense_lead for r in dense)
    checks.append(ClaimCheck(
        f"densest k, RGB-only ≤ {targets.dense_rgb_only:g} dB: Full − RGB-only ≥ +{targets.dense_lead:g} dB on every scene",
        verdict(ok), "; ".join(notes) or "-", _seeds_text(dense), ""))

    falls, worst = [], []
    for sc in scenes:
        pts = leads[sc]
        steps = [(a, b, a["lead_psnr"] - b["lead_psnr"], math.hypot(a["lead_psnr_std"] or 0.0, b["lead_psnr_std"] or 0.0))
                 for a, b in zip(pts, pts[1:])]
        if not steps:
            continue
        a, b, _, spread = max(steps, key=lambda s: s[2] - s[3])
        worst.append(f"{sc}: worst step k {a['k']:g} → {b['k']:g}, lead {a['lead_psnr']:+.2f} → "
                     f"{b['lead_psnr']:+.2f} (spread {spread:.2f})")
        falls += [sc for _, _, d, s in steps if d > s]
    checks.append(ClaimCheck(
        "Full − RGB-only does not fall as k rises beyond the seed spread, on any scene",
        verdict(None if not worst else not falls), "; ".join(worst) or "-", want, ""))
    return checks


def _signed(x: float) -> str:
    """A lead with a typographic minus, as the results tables print them."""
    return f"+{x:.2f}" if x >= 0 else f"−{-x:.2f}"


def _score(row: dict, method: str, metric: str = "psnr", digits: int = 2) -> str:
    return format_stat(Stat(row[f"{method}_{metric}"], row[f"{method}_{metric}_std"],
                            len(row[f"{method}_seeds"].split())), digits)


def _seeds(row: dict) -> str:
    full, rgb = row["full_seeds"].replace(" ", ", "), row["rgb-only_seeds"].replace(" ", ", ")
    return full if full == rgb else f"{rgb or '—'} / {full or '—'}"


def results_table(rows: list[dict]) -> list[str]:
    """The sweep's rows as a markdown table in order of k, then scene: the optical depth, the smoky
    input, each method's test PSNR (mean ± std over its seeds), the lead paired by seed, and the
    seeds (RGB-only / Full where they differ)."""
    lines = ["| scene | k | optical depth | smoky input | RGB-only | Full | Full − RGB-only | seeds |",
             "|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["k"], r["scene"])):
        lead = "—" if r["lead_psnr"] is None else _signed(r["lead_psnr"])
        lines.append(f"| {r['scene']} | {r['k']:g} | {r['optical_depth']:.2f} | {r['input_psnr']:.2f} | "
                     f"{_score(r, 'rgb-only')} | {_score(r, 'full')} | {lead} | {_seeds(r)} |")
    return lines


def lpips_table(rows: list[dict]) -> list[str]:
    """The same rows' test LPIPS (lower is better; mean ± std over seeds), and Full's lead as
    RGB-only − Full paired by seed, so that, as in PSNR, a positive lead is Full's; "—" where a
    run has no LPIPS."""
    lines = ["| scene | k | optical depth | RGB-only | Full | RGB-only − Full | seeds |",
             "|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["k"], r["scene"])):
        lead = "—" if r["lead_lpips"] is None else f"{r['lead_lpips']:+.3f}".replace("-", "−")
        lines.append(f"| {r['scene']} | {r['k']:g} | {r['optical_depth']:.2f} | {_score(r, 'rgb-only', 'lpips', 3)} | "
                     f"{_score(r, 'full', 'lpips', 3)} | {lead} | {_seeds(r)} |")
    return lines

