"""The benchmark's claims checked on the finished runs: the paper's method order on the mean over
scenes, Full against the smoky input, and every ablation against Full.

Table 1 averages each seed over the scenes it has, so while a seed is being filled its mean is
over fewer scenes than the others' and the ± mixes scenes with seeds. A claim is therefore only
checked over *complete* seeds: those where every variant it compares has a finished run on every
scene. The seeds left out, and how many of their runs have finished, are said beside the check.
A check with no complete seed reads "not yet" (neither holds nor fails).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from eval.regions import format_value, write_split_files
from eval.runs import ABLATIONS, VARIANTS, RunResult, variant_label
from eval.tables import seed_stat

METHOD_ORDER = ("full", "rgb-only", "imgdehaze-dcp")
"""The paper's Table 1 order, best first: each must beat the next on the mean over scenes."""
REFERENCE = "full"
SCENE_SHARE_ABOVE_INPUT = 0.8
"""Full must beat the smoky input on at least this share of the scenes (8 of 10)."""


@dataclass(frozen=True)
class ClaimCheck:
    """One claim (a row of claims.csv). ``holds`` is "yes", "no" or "not yet"."""

    claim: str
    holds: str
    measured: str
    seeds: str  # the complete seeds it was checked over
    left_out: str  # incomplete seeds and their finished runs, or ""


def _psnr_by_run(results: list[RunResult]) -> dict[tuple[str, str, int], float]:
    return {(r.scene, r.variant, r.seed): float(r.metrics["psnr"])
            for r in results if r.status == "ok" and r.metrics.get("psnr") is not None}


def input_psnr(results: list[RunResult]) -> dict[str, float]:
    """Per scene, the smoky input's test PSNR: from runs on the smoky frames (a dehazing
    baseline's own input column scores its dehazed frames instead)."""
    values: dict[str, list[float]] = {}
    for r in results:
        dehazed = r.variant in VARIANTS and VARIANTS[r.variant].dehazer is not None
        if r.status == "ok" and not dehazed and r.metrics.get("psnr_input") is not None:
            values.setdefault(r.scene, []).append(float(r.metrics["psnr_input"]))
    return {scene: sum(v) / len(v) for scene, v in values.items()}


def complete_seeds(results: list[RunResult], variants: tuple[str, ...]) -> tuple[list[int], str]:
    """The seeds where every variant has a finished PSNR on every scene of ``results``, and a
    description of the seeds that do not."""
    psnr = _psnr_by_run(results)
    scenes = sorted({r.scene for r in results})
    seeds = sorted({r.seed for r in results if r.variant in variants})
    done, left_out = [], []
    for seed in seeds:
        n = sum((s, v, seed) in psnr for s in scenes for v in variants)
        if n == len(scenes) * len(variants):
            done.append(seed)
        else:
            left_out.append(f"seed {seed}: {n} of {len(scenes) * len(variants)} runs")
    return done, "; ".join(left_out)


def _seed_list(seeds: list[int]) -> str:
    return ", ".join(str(s) for s in seeds) or "none complete"


def _stat_text(values_by_seed: dict[int, list[float]]) -> str:
    stat = seed_stat(values_by_seed)
    if stat.mean is None:
        return "-"
    return format_value(stat.mean) + ("" if stat.std is None else f" ± {format_value(stat.std)}")


def _verdict(ok: bool | None) -> str:
    return "not yet" if ok is None else ("yes" if ok else "no")


def method_checks(results: list[RunResult]) -> list[ClaimCheck]:
    """The paper's order pair by pair, and Full above the input on the mean and on most scenes."""
    psnr = _psnr_by_run(results)
    scenes = sorted({r.scene for r in results})
    floor = input_psnr(results)
    present = tuple(v for v in METHOD_ORDER if any(r.variant == v for r in results))
    checks = []
    for better, worse in zip(present, present[1:]):
        seeds, left_out = complete_seeds(results, (better, worse))
        high, low = (_by_seed(psnr, scenes, v, seeds) for v in (better, worse))
        ok = None if not seeds else seed_stat(high).mean > seed_stat(low).mean
        wins = sum(_scene_mean(psnr, sc, better, seeds) > _scene_mean(psnr, sc, worse, seeds)
                   for sc in scenes) if seeds else 0
        measured = ("-" if not seeds else
                    f"{variant_label(better)} {_stat_text(high)}, {variant_label(worse)} {_stat_text(low)} dB; "
                    f"ahead on {wins} of {len(scenes)} scenes")
        checks.append(ClaimCheck(f"{variant_label(better)} > {variant_label(worse)} on the mean over scenes",
                                 _verdict(ok), measured, _seed_list(seeds), left_out))
    if REFERENCE in present and all(sc in floor for sc in scenes):
        seeds, left_out = complete_seeds(results, (REFERENCE,))
        full = _by_seed(psnr, scenes, REFERENCE, seeds)
        floor_mean = sum(floor[sc] for sc in scenes) / len(scenes)
        stat = seed_stat(full)
        label = variant_label(REFERENCE)
        checks.append(ClaimCheck(
            f"{label} > smoky input on the mean over scenes",
            _verdict(None if not seeds else stat.mean > floor_mean),
            "-" if not seeds else f"{label} {_stat_text(full)}, input {format_value(floor_mean)} dB",
            _seed_list(seeds), left_out))
        need = math.ceil(SCENE_SHARE_ABOVE_INPUT * len(scenes))
        above = [sc for sc in scenes if seeds and _scene_mean(psnr, sc, REFERENCE, seeds) > floor[sc]]
        per_seed = ", ".join(f"seed {s}: {sum(psnr[(sc, REFERENCE, s)] > floor[sc] for sc in scenes)}"
                             for s in seeds)
        checks.append(ClaimCheck(
            f"{label} > smoky input on at least {need} of {len(scenes)} scenes (mean over seeds)",
            _verdict(None if not seeds else len(above) >= need),
            "-" if not seeds else f"{len(above)} of {len(scenes)} ({per_seed})",
            _seed_list(seeds), left_out))
    return checks


def ablation_checks(results: list[RunResult]) -> list[ClaimCheck]:
    """Each ablation at or below Full on the mean over scenes, over the seeds both complete."""
    psnr = _psnr_by_run(results)
    scenes = sorted({r.scene for r in results})
    checks = []
    for key in ABLATIONS:
        if not any(r.variant == key for r in results):
            continue
        seeds, left_out = complete_seeds(results, (REFERENCE, key))
        mine = _by_seed(psnr, scenes, key, seeds)
        full = _by_seed(psnr, scenes, REFERENCE, seeds)
        ok = None if not seeds else seed_stat(mine).mean <= seed_stat(full).mean
        above = [sc for sc in scenes if seeds and
                 _scene_mean(psnr, sc, key, seeds) > _scene_mean(psnr, sc, REFERENCE, seeds)]
        measured = "-" if not seeds else (
            f"{_stat_text(mine)} against {_stat_text(full)} dB "
            f"({seed_stat(mine).mean - seed_stat(full).mean:+.2f}); above Full on {len(above)} of "
            f"{len(scenes)} scenes" + (f" ({', '.join(above)})" if above else ""))
        checks.append(ClaimCheck(f"{variant_label(key)} ≤ {variant_label(REFERENCE)} on the mean over scenes",
                                 _verdict(ok), measured, _seed_list(seeds), left_out))
    return checks


def _by_seed(psnr: dict[tuple[str, str, int], float], scenes: list[str], variant: str,
             seeds: list[int]) -> dict[int, list[float]]:
    """A variant's PSNR on every scene, per seed (seeds where it has them all)."""
    return {s: [psnr[(sc, variant, s)] for sc in scenes] for s in seeds}


def _scene_mean(psnr: dict[tuple[str, str, int], float], scene: str, variant: str, seeds: list[int]) -> float:
    return sum(psnr[(scene, variant, s)] for s in seeds) / len(seeds)


def _per_scene_table(results: list[RunResult]) -> list[str]:
    """Per scene: each method's test PSNR at every seed it has, beside the input."""
    psnr = _psnr_by_run(results)
    floor = input_psnr(results)
    variants = [v for v in (*METHOD_ORDER, *ABLATIONS) if any(r.variant == v for r in results)]
    seeds = sorted({r.seed for r in results})
    lines = ["| scene | input | " + " | ".join(variant_label(v) for v in variants) + " |",
             "|---|---|" + "---|" * len(variants)]
    for scene in sorted({r.scene for r in results}):
        cells = [" / ".join(format_value(psnr.get((scene, v, s), math.nan)) for s in seeds) for v in variants]
        lines.append(f"| {scene} | {format_value(floor.get(scene, math.nan))} | " + " | ".join(cells) + " |")
    return lines


def _per_seed_table(results: list[RunResult]) -> list[str]:
    """Each variant's mean over scenes at every seed where it has all of them; otherwise how many."""
    psnr = _psnr_by_run(results)
    floor = input_psnr(results)
    scenes = sorted({r.scene for r in results})
    seeds = sorted({r.seed for r in results})
    variants = [v for v in (*METHOD_ORDER, *ABLATIONS) if any(r.variant == v for r in results)]
    lines = ["| variant | " + " | ".join(f"seed {s}" for s in seeds) + " |", "|---|" + "---|" * len(seeds)]
    for v in variants:
        cells = []
        for seed in seeds:
            have = [psnr[(sc, v, seed)] for sc in scenes if (sc, v, seed) in psnr]
            cells.append(format_value(sum(have) / len(have)) if len(have) == len(scenes)
                         else f"({len(have)} of {len(scenes)} scenes)")
        lines.append(f"| {variant_label(v)} | " + " | ".join(cells) + " |")
    if scenes and all(sc in floor for sc in scenes):
        floor_mean = format_value(sum(floor[sc] for sc in scenes) / len(scenes))
        lines.append("| smoky input | " + " | ".join([floor_mean] * len(seeds)) + " |")
    return lines


def _summary(checks: list[ClaimCheck], results: list[RunResult]) -> str:
    seeds = sorted({r.seed for r in results})
    lines = ["# The claims, checked on the finished runs", "",
             "Test PSNR (dB). Each claim is checked over the seeds where every variant it compares has "
             "finished on every scene: per seed the mean over scenes, then mean ± sample std over those "
             "seeds. Incomplete seeds are left out of the check and named.", "",
             "| claim | holds | measured | seeds | left out |", "|---|---|---|---|---|"]
    lines += [f"| {c.claim} | {c.holds} | {c.measured} | {c.seeds} | {c.left_out or '-'} |" for c in checks]
    lines += ["", "## Per seed: mean over scenes", "", *_per_seed_table(results)]
    lines += ["", f"## Per scene (seeds {' / '.join(str(s) for s in seeds)}; - not finished)", "",
              *_per_scene_table(results)]
    return "\n".join(lines) + "\n"


def write_claims(results: list[RunResult], out_dir: Path) -> dict[str, Path]:
    """claims.csv (one row per check) and claims.md (the checks and the per-scene, per-seed PSNRs)."""
    checks = method_checks(results) + ablation_checks(results)
    return write_split_files(out_dir, "claims", ClaimCheck, checks, _summary(checks, results), [])
