"""Table-2 rows that would train exactly like Full on a scene take Full's finished run.

Full's metrics.json records its Stage 3 plan (``stages.stage3_plan``, docs/results-format.md):
where the plan dropped a colour prior (the smoke colour held at the haze-line estimate, or no
smoke Gaussians), "w/o smoke_color" and "w/o mono" remove a term that was not there: with the
same scene, seed, data, settings and code they end with Full's bytes (tests/test_twins.py checks
this with the real trainer). The harness then records Full's result for them, marked
``same_as``, instead of training them; the tables say on how many scenes. Runs written before
the plan was recorded say the same through ``stages.smoke_colour.source`` = ``haze-lines``.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

from contracts.results_format import ResultsFormatError, read_metrics, stage3_plan
from eval.runs import RunResult, RunSpec

COLOUR_PRIOR_ABLATIONS = {"no-smoke-color": "smoke_color", "no-mono": "mono"}
"""Ablations that only zero a smoke-colour prior, and the term each zeroes."""

COLOUR_FIXED_REASON = ("Full held the smoke colour at the haze-line estimate, so this prior was not in its loss "
                       "and the run would train exactly like Full")


def twin_reason(variant: str, full_doc: dict[str, Any], where: Path = Path("metrics.json")) -> str | None:
    """Why ``variant`` would train exactly like the Full run whose metrics.json is ``full_doc``, or None."""
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
    """``twin_reason`` for the Full run folder ``full_dir`` (read from its metrics.json)."""
    return twin_reason(variant, read_metrics(full_dir), full_dir / "metrics.json")


def full_twins(specs: list[RunSpec], out: Path,
               finished: Callable[[RunSpec, Path], RunResult | None]) -> dict[str, RunResult]:
    """For each ablation run of the plan that Full's finished run stands for: its record (Full's
    metrics and run folder, this run's identity and config hash), keyed by its own run folder."""
    fulls = {(s.scene, s.seed, s.dataset_hash, s.code): s for s in specs if s.variant == "full"}
    twins: dict[str, RunResult] = {}
    for spec in specs:
        full = fulls.get((spec.scene, spec.seed, spec.dataset_hash, spec.code))
        if spec.variant not in COLOUR_PRIOR_ABLATIONS or full is None or dict(full.overrides) != dict(spec.overrides):
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
