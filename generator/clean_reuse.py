"""Generate a dataset at one smoke density scale with the clean passes of the same scene at another.

The clean passes are rendered without the smoke domain (`generator.ground_truth_refresh`), so the density
scale k never reaches them: every k of a scene has the same clean frames, byte for byte. They are
also the costliest pass (many samples, never denoised). A density sweep therefore renders them once
and each other k renders only what the smoke changes. The source must be a finished dataset whose
spec differs from the target's only in k and whose clean passes were rendered by today's render
code; anything else is refused with one line, never quietly rendered instead. dataset.json records
the source under `clean_reused`.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import time
from dataclasses import replace
from pathlib import Path

from generator.ground_truth_refresh import CLEAN, clean_modalities, copy_passes, finish_swap, recorded_spec
from generator.errors import GeneratorError
from generator.pipeline import generate, render_code_digest
from generator.spec import SceneSpec

log = logging.getLogger("generate-scene")


def _clean_code(meta: dict) -> str:
    """The render code that made a dataset's clean passes: a refresh's when they were re-rendered."""
    return str(meta.get("clean_refresh", {}).get("code_sha256", meta.get("code_sha256", "")))


def _problem(record: tuple[SceneSpec, dict] | None, target: SceneSpec) -> str | None:
    if record is None:
        return "not a finished dataset with a readable scene.yaml and dataset.json"
    recorded, meta = record
    if replace(recorded, smoke=replace(recorded.smoke, density_scale=target.smoke.density_scale)) != target:
        return f"its spec differs from {target.name!r} in more than smoke.density_scale"
    missing = [m for m in clean_modalities(target) if m not in clean_modalities(recorded)]
    if missing:
        return f"it has no clean pass for {', '.join(missing)}"
    if _clean_code(meta) != render_code_digest():
        return (f"its clean passes were rendered by other render code ({_clean_code(meta)[:12]}, "
                f"today {render_code_digest()[:12]})")
    return None


def clean_source_problem(source: Path, target: SceneSpec) -> str | None:
    """Why the dataset at `source` cannot provide its clean passes to `target`; None when it can."""
    return _problem(recorded_spec(source), target)


def generate_reusing_clean(target: SceneSpec, out: Path, source: Path, threads: int | None = None,
                           show_progress: bool = True, bake_store: Path | None = None, force: bool = False) -> Path:
    """Generate `target` at `out`, rendering every pass but the clean ones, which are copied from
    `source`. Staged beside `out` (`.NAME.clean-reuse/`, resumed after an interruption); with
    `force`, a dataset already at `out` is replaced once the new one validates."""
    out, source = Path(out).resolve(), Path(source).resolve()
    record = recorded_spec(source)
    problem = _problem(record, target)
    if record is None or problem:
        raise GeneratorError(f"{source / 'dataset.json'}: cannot provide its clean passes: {problem}")
    if out.exists() and not force:
        raise GeneratorError(f"{out}: already exists (use --force to replace it)")
    started = time.perf_counter()
    modalities = clean_modalities(target)
    staging = out.parent / f".{out.name}.clean-reuse"
    rendered = staging / "render"
    rest = replace(target, passes={m: tuple(p for p in ps if p != CLEAN) for m, ps in target.passes.items()})
    log.info("%s: clean passes (%s) from %s; rendering the rest", out.name, ", ".join(modalities), source)
    if not (rendered / "dataset.json").is_file():
        generate(rest, rendered, threads=threads, force=True, show_progress=show_progress, bake_store=bake_store)
    clean = [f"{m}.{CLEAN}" for m in modalities]
    copy_passes(source, rendered, clean, "its clean passes cannot be reused")
    source_meta = record[1]
    finish_swap(rendered, json.loads((rendered / "dataset.json").read_text()), target,
                source_meta["timings_s"]["render"], clean, {"clean_reused": {
        "passes": clean, "from": os.path.relpath(source, out),
        "source_spec_sha256": source_meta["spec_sha256"],
        "source_density_scale": source_meta["smoke"].get("density_scale", 1.0),
        "code_sha256": _clean_code(source_meta), "seconds": round(time.perf_counter() - started, 1),
        "note": "the clean passes never see the smoke, so they are the source's files; every other file "
                "was rendered for this dataset (timings_s.render gives the source's clean timings)"}})
    if out.exists():
        shutil.rmtree(out)
    os.replace(rendered, out)
    shutil.rmtree(staging)
    log.info("%s: generated in %.0f s with the clean passes of %s", out.name, time.perf_counter() - started,
             source.name)
    return out
