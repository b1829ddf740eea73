"""The benchmark's claims checked on the finished runs: the paper's method order on the mean over
scenes, Full's lead over RGB-only (on the mean and on every scene), Full against the smoky input,
Full's spread over seeds, every ablation against Full, and each Stage-1 row's gap to the oracle
Stage 1 (docs/benchmark.md, "What the tables promise").

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
RGB_ONLY = "rgb-only"
STAGE1_ROWS = ("full-estimated", "full-from-images")
"""Full with a Stage 1 that is not the oracle's, each compared with Full (the oracle Stage 1)."""


@dataclass(frozen=True)
class Targets:
    """The margins the claims are checked against (dB of test PSNR; scene values are each scene's
    mean over the complete seeds)."""

    lead_on_mean: float = 1.0
    """Full − RGB-only on the mean over scenes, at least."""
    lag_per_scene: float = 0.3
    """Full ≥ RGB-only − this on every scene: thermal never costs more than this."""
    full_mean: float | None = None
    """Full's mean over scenes, at least; only a benchmark with fixed scenes has one."""
    share_above_input: float = 0.8
    """Full beats the smoky input on at least this share of the scenes (8 of 10)."""
    seed_std: float = 1.0
    """Full's sample std over seeds on every scene, at most."""
    ablation_margin: float = 0.1
    """Every ablation ≤ Full + this on the mean over scenes."""
    stage1_loss: tuple[tuple[str, float], ...] = (("full-from-images", 1.0),)
    """Per Stage-1 row, the most it may lose against Full on the mean over scenes; a row not named
    is reported with its gap and no bound."""


def targets_for(profile: str) -> Targets:
    """The standard benchmark's targets: the relative ones, and Full's mean over its ten fixed
    scenes; other profiles have no absolute target."""
    return Targets(full_mean=23.0) if profile == "standard" else Targets()


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


def verdict(ok: bool | None) -> str:
    return "not yet" if ok is None else ("yes" if ok else "no")


def method_checks(results: list[RunResult], targets: Targets = Targets()) -> list[ClaimCheck]:
    """The paper's order pair by pair, Full's lead over RGB-only, Full's mean, Full above the input
    on the mean and on most scenes, and Full's spread over seeds."""
    return [*_order_checks(results), *_lead_checks(results, targets), *_input_checks(results, targets),
            *_spread_checks(results, targets)]


def _present(results: list[RunResult], variant: str) -> bool:
    return any(r.variant == variant for r in results)


def _order_checks(results: list[RunResult]) -> list[ClaimCheck]:
    psnr = _psnr_by_run(results)
    scenes = sorted({r.scene for r in results})
    present = tuple(v for v in METHOD_ORDER if _present(results, v))
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
                                 verdict(ok), measured, _seed_list(seeds), left_out))
    return checks


def _lead_checks(results: list[RunResult], targets: Targets) -> list[ClaimCheck]:
    """Full − RGB-only: at least ``lead_on_mean`` on the mean, no worse than −``lag_per_scene`` on
    any scene."""
    if not (_present(results, REFERENCE) and _present(results, RGB_ONLY)):
        return []
    psnr = _psnr_by_run(results)
    scenes = sorted({r.scene for r in results})
    seeds, left_out = complete_seeds(results, (REFERENCE, RGB_ONLY))
    full, rgb = (_by_seed(psnr, scenes, v, seeds) for v in (REFERENCE, RGB_ONLY))
    label, other = variant_label(REFERENCE), variant_label(RGB_ONLY)
    lead = seed_stat(full).mean - seed_stat(rgb).mean if seeds else math.nan
    per_seed = ", ".join(f"{sum(full[s]) / len(full[s]) - sum(rgb[s]) / len(rgb[s]):+.2f}" for s in seeds)
    mean_check = ClaimCheck(
        f"{label} − {other} ≥ +{targets.lead_on_mean:.2f} dB on the mean over scenes",
        verdict(None if not seeds else lead >= targets.lead_on_mean),
        "-" if not seeds else f"{lead:+.2f} dB ({label} {_stat_text(full)}, {other} {_stat_text(rgb)}); "
                              f"per seed {per_seed}",
        _seed_list(seeds), left_out)
    diffs = _scene_gaps(psnr, scenes, REFERENCE, RGB_ONLY, seeds) if seeds else {}
    below = [sc for sc in scenes if seeds and diffs[sc] < -targets.lag_per_scene]
    worst = min(diffs, key=lambda sc: diffs[sc]) if diffs else ""
    scene_check = ClaimCheck(
        f"{label} ≥ {other} − {targets.lag_per_scene:.2f} dB on every scene (mean over seeds)",
        verdict(None if not seeds else not below),
        "-" if not seeds else (f"lowest {worst} {diffs[worst]:+.2f} dB; below on {len(below)} of {len(scenes)} "
                               "scenes" + (f" ({', '.join(f'{sc} {diffs[sc]:+.2f}' for sc in below)})" if below else "")),
        _seed_list(seeds), left_out)
    return [mean_check, scene_check]


def _input_checks(results: list[RunResult], targets: Targets) -> list[ClaimCheck]:
    """Full's mean against its target and against the smoky input, and on how many scenes it beats
    the input."""
    if not _present(results, REFERENCE):
        return []
    psnr = _psnr_by_run(results)
    scenes = sorted({r.scene for r in results})
    floor = input_psnr(results)
    seeds, left_out = complete_seeds(results, (REFERENCE,))
    full = _by_seed(psnr, scenes, REFERENCE, seeds)
    stat = seed_stat(full)
    label = variant_label(REFERENCE)
    checks = []
    if targets.full_mean is not None:
        checks.append(ClaimCheck(
            f"{label} ≥ {targets.full_mean:.2f} dB on the mean over scenes",
            verdict(None if not seeds else stat.mean >= targets.full_mean),
            "-" if not seeds else f"{label} {_stat_text(full)} dB ({stat.mean - targets.full_mean:+.2f})",
            _seed_list(seeds), left_out))
    if not all(sc in floor for sc in scenes):
        return checks
    floor_mean = sum(floor[sc] for sc in scenes) / len(scenes)
    checks.append(ClaimCheck(
        f"{label} > smoky input on the mean over scenes",
        verdict(None if not seeds else stat.mean > floor_mean),
        "-" if not seeds else f"{label} {_stat_text(full)}, input {format_value(floor_mean)} dB",
        _seed_list(seeds), left_out))
    need = math.ceil(targets.share_above_input * len(scenes))
    above = [sc for sc in scenes if seeds and _scene_mean(psnr, sc, REFERENCE, seeds) > floor[sc]]
    per_seed = ", ".join(f"seed {s}: {sum(psnr[(sc, REFERENCE, s)] > floor[sc] for sc in scenes)}"
                         for s in seeds)
    checks.append(ClaimCheck(
        f"{label} > smoky input on at least {need} of {len(scenes)} scenes (mean over seeds)",
        verdict(None if not seeds else len(above) >= need),
        "-" if not seeds else f"{len(above)} of {len(scenes)} ({per_seed})",
        _seed_list(seeds), left_out))
    return checks


def _spread_checks(results: list[RunResult], targets: Targets) -> list[ClaimCheck]:
    """Full's sample std over the complete seeds on every scene; it needs two of them."""
    if not _present(results, REFERENCE):
        return []
    psnr = _psnr_by_run(results)
    scenes = sorted({r.scene for r in results})
    seeds, left_out = complete_seeds(results, (REFERENCE,))
    label = variant_label(REFERENCE)
    claim = f"{label}'s std over seeds ≤ {targets.seed_std:.2f} dB on every scene"
    if len(seeds) < 2:
        return [ClaimCheck(claim, "not yet", "needs two complete seeds", _seed_list(seeds), left_out)]
    std = {sc: seed_stat({s: [psnr[(sc, REFERENCE, s)]] for s in seeds}).std for sc in scenes}
    above = [sc for sc in scenes if std[sc] > targets.seed_std]
    worst = max(std, key=lambda sc: std[sc])
    measured = (f"largest {worst} {format_value(std[worst])}; above on {len(above)} of {len(scenes)} scenes"
                + (f" ({', '.join(f'{sc} {format_value(std[sc])}' for sc in above)})" if above else ""))
    return [ClaimCheck(claim, verdict(not above), measured, _seed_list(seeds), left_out)]


def ablation_checks(results: list[RunResult], targets: Targets = Targets()) -> list[ClaimCheck]:
    """Each ablation at most ``ablation_margin`` above Full on the mean over scenes, over the seeds
    both complete."""
    psnr = _psnr_by_run(results)
    scenes = sorted({r.scene for r in results})
    checks = []
    for key in ABLATIONS:
        if not _present(results, key):
            continue
        seeds, left_out = complete_seeds(results, (REFERENCE, key))
        mine = _by_seed(psnr, scenes, key, seeds)
        full = _by_seed(psnr, scenes, REFERENCE, seeds)
        ok = None if not seeds else seed_stat(mine).mean <= seed_stat(full).mean + targets.ablation_margin
        above = [sc for sc, gap in _scene_gaps(psnr, scenes, key, REFERENCE, seeds).items() if gap > 0] if seeds else []
        measured = "-" if not seeds else (
            f"{_stat_text(mine)} against {_stat_text(full)} dB "
            f"({seed_stat(mine).mean - seed_stat(full).mean:+.2f}); above Full on {len(above)} of "
            f"{len(scenes)} scenes" + (f" ({', '.join(above)})" if above else ""))
        checks.append(ClaimCheck(
            f"{variant_label(key)} ≤ {variant_label(REFERENCE)} + {targets.ablation_margin:.2f} dB on the mean over scenes",
            verdict(ok), measured, _seed_list(seeds), left_out))
    return checks


def stage1_checks(results: list[RunResult], targets: Targets = Targets()) -> list[ClaimCheck]:
    """Each row with a Stage 1 that is not the oracle's, against Full on the mean over the scenes
    where it finished: its gap stated, and held to its bound where it has one. A scene where the
    row failed (SfM that does not register) is named, never averaged in."""
    bounds = dict(targets.stage1_loss)
    checks = []
    for key in STAGE1_ROWS:
        if not _present(results, key):
            continue
        failed = sorted({r.scene for r in results if r.variant == key and r.status == "failed"})
        kept = [r for r in results if r.scene not in failed]
        psnr = _psnr_by_run(kept)
        scenes = sorted({r.scene for r in kept})
        seeds, left_out = complete_seeds(kept, (REFERENCE, key))
        mine, full = (_by_seed(psnr, scenes, v, seeds) for v in (key, REFERENCE))
        gap = seed_stat(mine).mean - seed_stat(full).mean if seeds and scenes else math.nan
        bound = bounds.get(key)
        label, reference = variant_label(key), variant_label(REFERENCE)
        if bound is None:
            claim, ok = f"{label}: its gap to {reference} on the mean over scenes, stated", bool(seeds and scenes)
        else:
            claim, ok = f"{label} ≥ {reference} − {bound:.2f} dB on the mean over scenes", gap >= -bound
        gaps = _scene_gaps(psnr, scenes, key, REFERENCE, seeds) if seeds else {}
        measured = "-" if not (seeds and scenes) else (
            f"{gap:+.2f} dB ({_stat_text(mine)} against {_stat_text(full)}) over {len(scenes)} scenes; lowest "
            + ", ".join(f"{sc} {gaps[sc]:+.2f}" for sc in sorted(gaps, key=lambda sc: gaps[sc])[:2]))
        if failed:
            measured += f"; failed on {', '.join(failed)} (report.md says why)"
        checks.append(ClaimCheck(claim, verdict(None if not (seeds and scenes) else ok), measured,
                                 _seed_list(seeds), left_out))
    return checks


def _by_seed(psnr: dict[tuple[str, str, int], float], scenes: list[str], variant: str,
             seeds: list[int]) -> dict[int, list[float]]:
    """A variant's PSNR on every scene, per seed (seeds where it has them all)."""
    return {s: [psnr[(sc, variant, s)] for sc in scenes] for s in seeds}


def _scene_mean(psnr: dict[tuple[str, str, int], float], scene: str, variant: str, seeds: list[int]) -> float:
    return sum(psnr[(scene, variant, s)] for s in seeds) / len(seeds)


def _scene_gaps(psnr: dict[tuple[str, str, int], float], scenes: list[str], variant: str, reference: str,
                seeds: list[int]) -> dict[str, float]:
    """Per scene, ``variant``'s mean over ``seeds`` minus ``reference``'s."""
    return {sc: _scene_mean(psnr, sc, variant, seeds) - _scene_mean(psnr, sc, reference, seeds) for sc in scenes}


def _listed(results: list[RunResult]) -> list[str]:
    """The variants the per-scene and per-seed tables show, in the tables' order."""
    return [v for v in (*METHOD_ORDER, *STAGE1_ROWS, *ABLATIONS) if _present(results, v)]


def _per_scene_table(results: list[RunResult]) -> list[str]:
    """Per scene: each method's test PSNR at every seed it has, beside the input."""
    psnr = _psnr_by_run(results)
    floor = input_psnr(results)
    variants = _listed(results)
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
    variants = _listed(results)
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


def claims_table(checks: list[ClaimCheck]) -> list[str]:
    """The checks as the lines of a markdown table, one row per check."""
    return ["| claim | holds | measured | seeds | left out |", "|---|---|---|---|---|",
            *(f"| {c.claim} | {c.holds} | {c.measured} | {c.seeds} | {c.left_out or '-'} |" for c in checks)]


def _summary(checks: list[ClaimCheck], results: list[RunResult]) -> str:
    seeds = sorted({r.seed for r in results})
    lines = ["# The claims, checked on the finished runs", "",
             "Test PSNR (dB). Each claim is checked over the seeds where every variant it compares has "
             "finished on every scene: per seed the mean over scenes, then mean ± sample std over those "
             "seeds. Incomplete seeds are left out of the check and named.", "",
             *claims_table(checks)]
    lines += ["", "## Per seed: mean over scenes", "", *_per_seed_table(results)]
    lines += ["", f"## Per scene (seeds {' / '.join(str(s) for s in seeds)}; - not finished)", "",
              *_per_scene_table(results)]
    return "\n".join(lines) + "\n"


def write_claims(results: list[RunResult], out_dir: Path, targets: Targets = Targets()) -> dict[str, Path]:
    """claims.csv (one row per check) and claims.md (the checks and the per-scene, per-seed PSNRs)."""
    checks = method_checks(results, targets) + stage1_checks(results, targets) + ablation_checks(results, targets)
    return write_split_files(out_dir, "claims", ClaimCheck, checks, _summary(checks, results), [])
