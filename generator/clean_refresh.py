"""Re-render the smoke-free ground truth of a finished dataset at more samples, leaving every
training input as it is.

The clean passes are ground truth and never denoised, so their Monte Carlo noise is error in
every score against them. A dataset whose spec differs from today's only in the cameras'
`clean_samples` needs no new simulation and no new smoky frame: only its clean passes are
rendered again (the scene without its smoke domain, so no bake; same seed, same cameras, same
thermal sensor) and swapped in. Everything else stays byte for byte, and dataset.json says what
was re-rendered under `clean_refresh`.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from contracts.atomic import write_json
from contracts.dataset_format import PASS_FILES, file_path, transforms_name, validate_dataset
from generator import postprocess
from generator.errors import GeneratorError, SpecError
from generator.pipeline import generate, render_code_digest, versions
from generator.spec import SceneSpec, load_spec_file

log = logging.getLogger("generate-scene")
CLEAN = "clean"


def rendered_clean_samples(meta: dict[str, Any]) -> dict[str, int]:
    """The samples each camera's clean pass was rendered with. Datasets written before the field
    existed rendered their clean passes at the smoky pass's samples."""
    return {m: int(r.get("clean_samples", r["samples"])) for m, r in meta["render"].items()}


def with_clean_samples(spec: SceneSpec, samples: dict[str, int]) -> SceneSpec:
    rig = spec.rig
    return replace(spec, rig=replace(
        rig, rgb=replace(rig.rgb, clean_samples=samples.get("rgb", rig.rgb.clean_samples)),
        thermal=replace(rig.thermal, clean_samples=samples.get("thermal", rig.thermal.clean_samples))))


def clean_modalities(spec: SceneSpec) -> tuple[str, ...]:
    return tuple(m for m, passes in spec.passes.items() if CLEAN in passes)


def recorded_spec(dataset: Path) -> tuple[SceneSpec, dict[str, Any]] | None:
    """The spec a finished dataset was made from, with its clean passes' samples as rendered, and
    its dataset.json; None when either file is missing or the spec no longer reads back."""
    meta_path, spec_path = dataset / "dataset.json", dataset / "scene.yaml"
    if not (meta_path.is_file() and spec_path.is_file()):
        return None
    meta = json.loads(meta_path.read_text())
    try:
        return with_clean_samples(load_spec_file(spec_path), rendered_clean_samples(meta)), meta
    except (SpecError, KeyError) as exc:  # a record from an older spec schema
        log.info("%s: its recorded spec does not read back (%s)", dataset, exc)
        return None


def clean_refresh_needed(dataset: Path, target: SceneSpec) -> bool:
    """True when the finished dataset at `dataset` was made from `target` except for the clean
    passes' samples (so re-rendering those makes it `target`'s dataset)."""
    record = recorded_spec(dataset)
    if record is None or record[1].get("spec_sha256") == target.sha256():
        return False
    recorded = record[0]
    if recorded == target or not clean_modalities(target):
        return False
    return with_clean_samples(recorded, {m: getattr(target.rig, m).clean_samples for m in ("rgb", "thermal")}) == target


def copy_clean_passes(source: Path, into: Path, modalities: tuple[str, ...], why_not: str) -> None:
    """Copy the clean pass files of `modalities` from dataset `source` into dataset `into`, once
    both are shown to hold the same cameras at the same timestamps (`why_not` ends the error)."""
    for m in modalities:
        if json.loads((source / transforms_name(m)).read_text()) != json.loads((into / transforms_name(m)).read_text()):
            raise GeneratorError(f"{source / transforms_name(m)}: other cameras or timestamps than "
                                 f"{into / transforms_name(m)}; {why_not}")
    for m in modalities:
        for frame in json.loads((into / transforms_name(m)).read_text())["frames"]:
            for pf in PASS_FILES[(m, CLEAN)]:
                dst = file_path(into, pf, frame["file_stem"])
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(file_path(source, pf, frame["file_stem"]), dst)


def finish_clean_swap(dataset: Path, meta: dict[str, Any], target: SceneSpec, clean_timings: dict[str, Any],
                      key: str, record: dict[str, Any]) -> None:
    """Make `dataset`, whose clean passes were just swapped in, `target`'s dataset: its metadata
    describes `target` (passes, clean samples, spec hash, statistics), `meta[key]` says where the
    clean passes came from (their per-frame time from `clean_timings`), and the folder validates."""
    stems = {m: [f["file_stem"] for f in json.loads((dataset / transforms_name(m)).read_text())["frames"]]
             for m in target.passes}
    meta["passes"] = {m: list(p) for m, p in target.passes.items()}
    meta["spec_sha256"] = target.sha256()
    for m in clean_modalities(target):
        meta["render"][m]["clean_samples"] = getattr(target.rig, m).clean_samples
        meta["timings_s"]["render"][f"{m}.{CLEAN}"] = clean_timings.get(f"{m}.{CLEAN}")
    meta["stats"] = postprocess.scene_stats(dataset, stems, target.passes)
    meta[key] = record
    write_json(dataset / "dataset.json", meta)
    (dataset / "scene.yaml").write_text(target.to_yaml())
    validate_dataset(dataset)


def refresh_clean(dataset: Path, target: SceneSpec, threads: int | None = None, show_progress: bool = True) -> Path:
    """Re-render the clean passes of `dataset` at `target`'s clean_samples and swap them in.

    Staged beside the dataset (`.NAME.clean-refresh/`, resumed after an interruption); the
    dataset is replaced only once the new one validates."""
    dataset = Path(dataset).resolve()
    staging = dataset.parent / f".{dataset.name}.clean-refresh"
    if not dataset.exists() and (staging / "old").exists():  # stopped between the two renames
        os.replace(staging / "dataset", dataset)
        shutil.rmtree(staging)
        return dataset
    if not clean_refresh_needed(dataset, target):
        raise GeneratorError(f"{dataset / 'scene.yaml'}: the dataset differs from spec {target.name!r} in more "
                             "than clean_samples (or not at all); regenerate it instead")
    started = time.perf_counter()
    meta = json.loads((dataset / "dataset.json").read_text())
    before = rendered_clean_samples(meta)
    modalities = clean_modalities(target)
    rendered = staging / "render"
    clean_only = replace(target, passes={m: (CLEAN,) for m in modalities})
    log.info("%s: re-rendering the clean passes (%s) at %s samples, were %s", dataset.name, ", ".join(modalities),
             {m: getattr(target.rig, m).clean_samples for m in modalities}, before)
    if not (rendered / "dataset.json").is_file():
        generate(clean_only, rendered, threads=threads, force=True, show_progress=show_progress)
    new_meta = json.loads((rendered / "dataset.json").read_text())
    fresh = staging / "dataset"
    if fresh.exists():
        shutil.rmtree(fresh)
    shutil.copytree(dataset, fresh)
    copy_clean_passes(rendered, fresh, modalities, "regenerate the dataset instead")
    after = {m: getattr(target.rig, m).clean_samples for m in modalities}
    finish_clean_swap(fresh, meta, target, new_meta["timings_s"]["render"], "clean_refresh", {
        "passes": [f"{m}.{CLEAN}" for m in modalities], "clean_samples_before": before, "clean_samples": after,
        "code_sha256": render_code_digest(), "versions": {**versions(), "blender": new_meta["versions"]["blender"]},
        "seconds": round(time.perf_counter() - started, 1),
        "note": "only the clean passes were rendered again; every other file is the original dataset's"})
    old = staging / "old"
    os.replace(dataset, old)
    os.replace(fresh, dataset)
    shutil.rmtree(staging)
    log.info("%s: clean passes re-rendered in %.0f s", dataset.name, time.perf_counter() - started)
    return dataset
