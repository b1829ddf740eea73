"""Adopt finished runs that were trained under another cache key only because the trainer's code
digest differs (another Python version), into this checkout's ``--out``.

Why: another machine (a GPU host, a cluster node) may run another Python, whose ``ast.dump`` gives the unchanged trainer
another digest (docs/scale-out.md), so its runs are not found here. A run is adopted only when
it is provably the run this plan asks for:

- its record's ``config_hash`` is this plan's key for the same scene, variant and seed with only
  the code digest replaced by the one it recorded (so method, settings, profile and dataset
  content are equal), its status is ``ok`` and its metrics.json passes the results contract;
- its trainer sources (``eval.sources.sources_sha256``, raw bytes, Python-independent) equal
  this checkout's.

It is copied under this checkout's key (staging folder, then one rename), its ``harness.json``
names where it came from (``adopted_from``), and its metrics.json and provenance stay as made.
"""
from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

from contracts.atomic import write_json
from contracts.recorded_paths import recorded_path
from contracts.results_format import ResultsFormatError, read_metrics
from eval.harness import TRAINER_ENTRY, HarnessConfig, default_generate, finished_run, make_plan
from eval.runs import RunResult, RunSpec
from eval.sources import sources_sha256


@dataclass(frozen=True)
class Adoption:
    """One planned run looked for in the source folder: adopted, or why not."""

    scene: str
    variant: str
    seed: int
    source: str
    adopted: bool
    reason: str


def _candidates(source_out: Path, spec: RunSpec) -> list[Path]:
    return sorted((Path(source_out) / "runs" / spec.scene / spec.variant).glob(f"seed{spec.seed}-*/harness.json"))


def _check(spec: RunSpec, record_path: Path, local_sources: str) -> str:
    """"" when the run at record_path is this spec's run under its own code digest, else why not."""
    try:
        rec = json.loads(record_path.read_text())
    except (OSError, ValueError) as exc:
        return f"{record_path}: unreadable ({exc})"
    if rec.get("status") != "ok":
        return f"{record_path}: field 'status' is {rec.get('status')!r}, not 'ok'"
    digest = rec.get("code_digest")
    if not digest:
        return f"{record_path}: no field 'code_digest' (recorded before adoption was possible)"
    theirs = replace(spec, code=digest)
    if rec.get("config_hash") != theirs.hash():
        return f"{record_path}: field 'config_hash' is not this plan's key with its digest (settings or dataset differ)"
    try:
        read_metrics(record_path.parent)
    except ResultsFormatError as exc:
        return str(exc)
    if digest != spec.code and rec.get("sources_sha256") != local_sources:
        return (f"{record_path}: field 'sources_sha256' differs from this checkout's trainer sources "
                f"({str(rec.get('sources_sha256') or 'missing')[:12]} != {local_sources[:12]})")
    return ""


def _copy_in(spec: RunSpec, source_dir: Path, dest: Path, local_sources: str) -> None:
    staging = dest.with_name(f".{dest.name}.adopting")
    if staging.exists():
        shutil.rmtree(staging)
    shutil.copytree(source_dir, staging)
    rec = RunResult.from_json(json.loads((staging / "harness.json").read_text()))
    adopted_from = (f"{recorded_path(source_dir)} (key {rec.config_hash[:12]}, trainer digest "
                    f"{rec.code_digest[:8]}, trained on {rec.device}): its key with this "
                    f"checkout's digest {spec.code[:8]} is this run's, and its trainer sources equal this "
                    f"checkout's (sources_sha256 {local_sources[:12]})")
    rec = replace(rec, adopted_from=adopted_from, config_hash=spec.hash(), run_dir=str(dest), dataset=spec.dataset,
                  code_digest=spec.code)
    write_json(staging / "harness.json", rec.to_json())
    os.replace(staging, dest)


def adopt_runs(cfg: HarnessConfig, source_out: Path, dry_run: bool = False) -> list[Adoption]:
    """For every run of ``cfg``'s plan not finished in ``cfg.out``, adopt the matching finished run
    of ``source_out`` when the checks above pass; report every planned run found there."""
    plan = make_plan(cfg, default_generate)
    local_sources = sources_sha256(TRAINER_ENTRY)
    found = []
    for spec in plan.runs:
        dest = spec.run_dir(Path(cfg.out)).resolve()
        if finished_run(spec, dest) is not None:
            continue
        reasons = []
        for record_path in _candidates(source_out, spec):
            reason = _check(spec, record_path, local_sources)
            if reason:
                reasons.append(reason)
                continue
            if dest.exists():
                reason = f"{dest}: an unfinished run of this key is here; finish or remove it first"
            elif not dry_run:
                dest.parent.mkdir(parents=True, exist_ok=True)
                _copy_in(spec, record_path.parent, dest, local_sources)
            found.append(Adoption(spec.scene, spec.variant, spec.seed, str(record_path.parent), not reason, reason))
            break
        else:
            found += [Adoption(spec.scene, spec.variant, spec.seed, "", False, r) for r in reasons]
    return found
