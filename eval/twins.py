"""Runs that would train exactly like Full on a scene take Full's finished run.

Full's metrics.json records its Stage 3 plan (``stages.stage3_plan``, docs/results-format.md):
where the plan dropped a colour prior (the smoke colour held at the haze-line estimate, or no
smoke Gaussians), "w/o smoke_color" and "w/o mono" remove a term that was not there: with the
same scene, seed, data, settings and code they end with Full's bytes. Runs written before the
plan was recorded say the same through ``stages.smoke_colour.source`` = ``haze-lines``. The
candidate ``floor-by-meeting-trust`` changes the mask floor only where Full's floor read a haze-line
meeting point: where the lines gave none, or too few of them met, or the floor reads no haze line,
its floor is Full's, and so is every byte (tests/test_twins.py checks both with the real trainer).
The candidate ``carve-where-smoky`` changes only how the joined start is carved: where Full's
Stage 3 started from one surface (the thermal Stage 2 alone under dense, dark smoke), it is Full.
The harness then records Full's result for them, marked ``same_as``, instead of training them;
the tables say on how many scenes.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Iterable

from contracts.results_format import ResultsFormatError, read_metrics, stage3_plan
from eval.runs import VARIANTS, RunResult, RunSpec

COLOUR_PRIOR_ABLATIONS = {"no-smoke-color": "smoke_color", "no-mono": "mono"}
"""Ablations that only zero a smoke-colour prior, and the term each zeroes."""

COLOUR_FIXED_REASON = ("Full held the smoke colour at the haze-line estimate, so this prior was not in its loss "
                       "and the run would train exactly like Full")


MEETING_CANDIDATE = "floor-by-meeting-trust"
"""The candidate that reads the haze lines' meeting point by its weight (``loss.mask_floor_meeting``)."""

CARVE_CANDIDATE = "carve-where-smoky"
"""The candidate that carves Stage 3's joined start by smoke (``stage3.carve_by``)."""

TWIN_VARIANTS = (*COLOUR_PRIOR_ABLATIONS, MEETING_CANDIDATE, CARVE_CANDIDATE)
"""Variants that may stand on Full's run, each by its own rule (``twin_reason``)."""


def carve_twin_reason(full_doc: dict[str, Any]) -> str | None:
    """Why ``carve-where-smoky`` would train exactly like the Full run whose metrics.json is
    ``full_doc``, or None: Full's Stage 3 started from one surface, not the joined one
    (``stages.surface_union`` recorded as null), so no RGB Gaussian was carved."""
    stages = full_doc.get("stages") or {}
    if "surface_union" not in stages or stages["surface_union"] is not None:
        return None
    return "Full's Stage 3 started from one surface, not the joined one, so nothing was carved and the run would train exactly like Full"


def meeting_twin_reason(full_doc: dict[str, Any], config: dict[str, Any], where: Path) -> str | None:
    """Why ``floor-by-meeting-trust`` would floor exactly as the Full run did (metrics.json
    ``full_doc``, config.json ``config``), or None: Full's floor reads no haze line, or the lines
    gave no point, or fewer of them met than the point needs (``stage3.smoke_color_min_meeting``),
    where the point's weight is 0 and Full used none; or the point's weight is 1, where the blend
    is Full's floor. The weight is the trust's line and meeting ramps, and the recorded surface
    trust is their product with a darkness ramp, so a surface trust of 1 means a weight of 1."""
    plan = stage3_plan(full_doc, where)
    if plan is None:
        return None
    if plan["mask_floor"] not in ("estimated-meeting", "estimated-bound"):
        return f"Full's mask floor ({plan['mask_floor']}) does not read the haze lines, so the run would train exactly like Full"
    lines = ((full_doc.get("stages") or {}).get("smoke_colour") or {}).get("haze_lines")
    if lines is None or lines.get("colour") is None:
        return "the haze lines gave Full no meeting point, so both floors read none and the run would train exactly like Full"
    least = config["stage3"]["smoke_color_min_meeting"]
    if lines["meeting_fraction"] < least:
        return (f"{lines['meeting_fraction']:.2f} of the haze lines met, under the {least} a point needs, so both floors "
                "read none and the run would train exactly like Full")
    if (lines.get("surface_trust") or 0.0) >= 1.0:
        return ("the haze lines' point was fully trusted (surface trust 1), so its weight is 1, the blended floor is "
                "Full's and the run would train exactly like Full")
    return None


def twin_reason(variant: str, full_doc: dict[str, Any], where: Path = Path("metrics.json"),
                config: dict[str, Any] | None = None) -> str | None:
    """Why ``variant`` would train exactly like the Full run whose metrics.json is ``full_doc`` (and
    config.json ``config``, which the meeting candidate reads), or None."""
    if variant == MEETING_CANDIDATE:
        return None if config is None else meeting_twin_reason(full_doc, config, where)
    if variant == CARVE_CANDIDATE:
        return carve_twin_reason(full_doc)
    term = COLOUR_PRIOR_ABLATIONS.get(variant)
    if term is None:
        return None
    plan = stage3_plan(full_doc, where)
    if plan is not None:
        why = plan["dropped"].get(term)
        return (f"Full's Stage 3 plan left the {term} term out ({why}), so the run would train exactly like Full"
                if why else None)
    colour = (full_doc.get("stages") or {}).get("smoke_colour") or {}
    return COLOUR_FIXED_REASON if colour.get("source") == "haze-lines" else None


def run_twin_reason(variant: str, full_dir: Path) -> str | None:
    """``twin_reason`` for the Full run folder ``full_dir`` (its metrics.json and config.json)."""
    if variant not in TWIN_VARIANTS:
        return None
    config = json.loads((full_dir / "config.json").read_text()) if (full_dir / "config.json").is_file() else None
    return twin_reason(variant, read_metrics(full_dir), full_dir / "metrics.json", config)


def stood_for(variants: Iterable[str], found: dict[str, tuple[Path, Any]]) -> list[str]:
    """The ``variants`` with no finished run of their own in ``found`` (variant -> (run folder,
    record) of one scene, seed and trainer) that Full's finished run there stands for: how a study
    reads back the runs the harness took from Full (``full_twins``)."""
    if "full" not in found:
        return []
    return [v for v in variants if v not in found and run_twin_reason(v, found["full"][0])]


def twin_source(spec: RunSpec, specs: list[RunSpec]) -> RunSpec | None:
    """The Full run of ``specs`` whose finished run may stand for ``spec`` (same scene, seed, data
    and code, and Full's settings plus the variant's own), or None; its record decides."""
    if spec.variant not in TWIN_VARIANTS:
        return None
    for full in specs:
        if full.variant == "full" and (full.scene, full.seed, full.dataset_hash, full.code) == \
                (spec.scene, spec.seed, spec.dataset_hash, spec.code) and \
                dict(spec.overrides) == {**dict(full.overrides), **VARIANTS[spec.variant].overrides}:
            return full
    return None


def full_twins(specs: list[RunSpec], out: Path,
               finished: Callable[[RunSpec, Path], RunResult | None]) -> dict[str, RunResult]:
    """For each run of the plan that Full's finished run stands for: its record (Full's
    metrics and run folder, this run's identity and config hash), keyed by its own run folder."""
    twins: dict[str, RunResult] = {}
    for spec in specs:
        full = twin_source(spec, specs)
        if full is None:
            continue
        full_dir = full.run_dir(out).resolve()
        done = finished(full, full_dir)
        if done is None:
            continue
        try:
            reason = run_twin_reason(spec.variant, full_dir)
        except ResultsFormatError:
            continue
        if reason:
            twins[str(spec.run_dir(out).resolve())] = replace(
                done, variant=spec.variant, config_hash=spec.hash(), cached=True, stage2_from="", same_as="full",
                same_as_reason=reason)
    return twins
