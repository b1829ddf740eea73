"""Re-render ground truth of a finished dataset, leaving every training input as it is.

Ground-truth passes are for scoring only, so they can be rendered again, or added, without
touching a frame a trainer reads. Two cases, handled in one render:

- **ground truth at more samples**: a dataset whose spec differs from today's in the cameras'
  `clean_samples` needs no new smoky frame; only the passes rendered at those samples (clean,
  shadowed) are rendered again and swapped in. The clean passes alone need no smoke domain, so
  no bake;
- **ground-truth passes the dataset lacks** (such as `rgb.shadowed`, added to the format after
  the ten standard datasets were made): only those are rendered. A pass that needs the smoke
  (`shadowed`) bakes the simulation again; a bake is a function of the spec and the code, so it
  should give the smoke of the smoky frames, and the refresh checks that it does by rendering
  the RGB smoke opacity again beside it and comparing it with the dataset's. It refuses with one
  line when they differ, before anything is swapped in.

Same seed, same cameras, same thermal sensor. Everything else stays byte for byte, and
dataset.json says what was rendered again (`clean_refresh`, `passes_added`).
"""
from __future__ import annotations

import json
import logging
import math
import os
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from blender.job import CLEAN_SAMPLE_PASSES, SMOKE_PASSES
from contracts.atomic import write_json
from contracts.dataset_format import (GROUND_TRUTH_FOLDERS, PASS_FILES, file_path, has_frame, transforms_name,
                                     validate_dataset)
from contracts.imageio import read_exr_channel
from generator.dataset_stats import scene_stats
from generator.errors import GeneratorError, SpecError
from generator.job import without_absent_passes
from generator.pipeline import generate, render_code_digest, versions
from generator.spec import MODALITIES, PASSES, SceneSpec, load_spec_file

log = logging.getLogger("generate-scene")
CLEAN = "clean"
SMOKE_CHECK = ("rgb", "smoke_alpha")
"""The pass rendered again beside an added pass that needs the smoke, to show the new bake is the
dataset's smoke."""
SMOKE_CHECK_BLOCK = 8
"""The check compares the mean opacity of BLOCK×BLOCK pixel blocks, not pixels: a dataset's
opacity pass may come from an older, noisier estimator (all-or-nothing samples before the
absorption estimator), and its per-pixel Monte Carlo noise (house 0.0128 RMS in a frame, rover
0.0347) averages away over a block (0.0013, 0.0043) while a different smoke does not
(docs/experiments/2026-12-07-smoke-check-against-estimator-noise.md)."""
SMOKE_CHECK_RMS = 0.004
"""Block-mean differences up to this RMS in a frame always pass: under one frame of the smoke's
own motion on house (0.0097 at least), the thinnest standard smoke."""
SMOKE_CHECK_NOISE = 2.0
"""Above SMOKE_CHECK_RMS a frame passes while its block-mean RMS is at most this many times what
the difference's own pixel noise leaves over a block (``opacity_difference``): white noise leaves
1 (rover's rebake 0.85-1.06 a frame), while a smoother difference, such as one frame of the
smoke's motion, does not shrink over a block (5-34 times on house, forest and rover)."""


@dataclass(frozen=True)
class OpacityDifference:
    """Two opacity frames compared: the RMS of their difference per pixel, over SMOKE_CHECK_BLOCK-pixel
    block means, and what white pixel noise alone would leave over a block (the within-block
    spread's RMS, unbiased, over the block side)."""

    pixel_rms: float
    block_rms: float
    noise_block_rms: float

    @property
    def allowed(self) -> float:
        """The largest block RMS this frame may show and pass."""
        return max(SMOKE_CHECK_RMS, SMOKE_CHECK_NOISE * self.noise_block_rms)

    @property
    def share_of_allowed(self) -> float:
        """How much of its allowance the frame uses: over 1 refuses it."""
        return self.block_rms / self.allowed


def opacity_difference(a: np.ndarray, b: np.ndarray) -> OpacityDifference:
    """Compare two opacity frames over SMOKE_CHECK_BLOCK-pixel blocks (the ragged edge rows and
    columns past whole blocks left out)."""
    block, n = SMOKE_CHECK_BLOCK, SMOKE_CHECK_BLOCK ** 2
    h, w = (a.shape[0] // block) * block, (a.shape[1] // block) * block
    d = (np.asarray(a, np.float64) - np.asarray(b, np.float64))[:h, :w]
    blocks = d.reshape(h // block, block, w // block, block)
    means = blocks.mean(axis=(1, 3), keepdims=True)
    spread = float(np.sqrt(np.mean((blocks - means) ** 2) * n / (n - 1)))
    return OpacityDifference(float(np.sqrt(np.mean(d ** 2))), float(np.sqrt(np.mean(means ** 2))), spread / block)


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


def ground_truth_only(modality: str, name: str) -> bool:
    """Whether every file of the pass is ground truth for scoring only, so adding it to a dataset
    changes nothing a trainer reads (the smoke masks, the oracle Stage 1, are not)."""
    return all(pf.folder in GROUND_TRUTH_FOLDERS for pf in PASS_FILES[(modality, name)])


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


@dataclass(frozen=True)
class Refresh:
    """What re-rendering makes a finished dataset the target's, by camera: the passes rendered at
    the clean samples (clean, shadowed) that go to the target's samples, and the ground-truth
    passes the dataset lacks."""

    resampled: dict[str, tuple[str, ...]]
    added: dict[str, tuple[str, ...]]

    def items(self) -> set[tuple[str, str]]:
        return {(m, p) for part in (self.resampled, self.added) for m, ps in part.items() for p in ps}

    def render_passes(self, checked: bool) -> dict[str, tuple[str, ...]]:
        """The passes to render, with the smoke check beside them when ``checked``."""
        wanted = self.items() | ({SMOKE_CHECK} if checked else set())
        return {m: tuple(p for p in PASSES if (m, p) in wanted) for m in MODALITIES if any(w[0] == m for w in wanted)}

    def swapped(self) -> list[str]:
        """The passes whose files come from the new render, as MODALITY.PASS."""
        return [f"{m}.{p}" for m in MODALITIES for p in PASSES if (m, p) in self.items()]

    @property
    def needs_smoke(self) -> bool:
        return any(p in SMOKE_PASSES for _, p in self.items())


def refresh_plan(dataset: Path, target: SceneSpec) -> Refresh | None:
    """How to make the finished dataset at `dataset` `target`'s by re-rendering ground truth alone;
    None when it already is, or when it differs in anything else (then it must be regenerated)."""
    record = recorded_spec(dataset)
    target = without_absent_passes(target)
    if record is None or record[1].get("spec_sha256") == target.sha256():
        return None
    recorded = record[0]
    if any(p not in target.passes.get(m, ()) for m, ps in recorded.passes.items() for p in ps):
        return None  # the target drops a pass: regenerate
    added = {m: tuple(p for p in ps if p not in recorded.passes.get(m, ())) for m, ps in target.passes.items()}
    added = {m: ps for m, ps in added.items() if ps}
    if not all(ground_truth_only(m, p) for m, ps in added.items() for p in ps):
        return None
    samples = {m: getattr(target.rig, m).clean_samples for m in MODALITIES}
    if with_clean_samples(replace(recorded, passes=target.passes), samples) != target:
        return None
    resampled = {m: tuple(p for p in ps if p in CLEAN_SAMPLE_PASSES) for m, ps in recorded.passes.items()
                 if getattr(recorded.rig, m).clean_samples != samples[m]}
    resampled = {m: ps for m, ps in resampled.items() if ps}
    return Refresh(resampled, added) if resampled or added else None


CAMERA_REL_TOL = 1e-9
"""Numbers in two camera files agree to this relative tolerance: the cameras are computed again
from the spec, and another CPU's libm may round a pose's sines and cosines in the last bit."""


def same_cameras(a: Any, b: Any) -> bool:
    """Two parsed camera files hold the same cameras: the same structure and strings, and numbers
    equal to CAMERA_REL_TOL (never a pose off by more than rounding)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_cameras(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_cameras(x, y) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return (isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool)
                and not isinstance(b, bool) and math.isclose(a, b, rel_tol=CAMERA_REL_TOL, abs_tol=1e-12))
    return a == b


def copy_passes(source: Path, into: Path, passes: list[str], why_not: str) -> None:
    """Copy the files of `passes` (MODALITY.PASS) from dataset `source` into dataset `into`, once
    both are shown to hold the same cameras at the same timestamps (`why_not` ends the error)."""
    modalities = sorted({p.split(".")[0] for p in passes})
    for m in modalities:
        if not same_cameras(json.loads((source / transforms_name(m)).read_text()),
                            json.loads((into / transforms_name(m)).read_text())):
            raise GeneratorError(f"{source / transforms_name(m)}: other cameras or timestamps than "
                                 f"{into / transforms_name(m)}; {why_not}")
    for item in passes:
        m, name = item.split(".")
        for frame in json.loads((into / transforms_name(m)).read_text())["frames"]:
            if not has_frame(m, name, frame["split"]):
                continue
            for pf in PASS_FILES[(m, name)]:
                dst = file_path(into, pf, frame["file_stem"])
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(file_path(source, pf, frame["file_stem"]), dst)


def finish_swap(dataset: Path, meta: dict[str, Any], target: SceneSpec, timings: dict[str, Any],
                swapped: list[str], records: dict[str, dict[str, Any]]) -> None:
    """Make `dataset`, whose `swapped` passes (MODALITY.PASS) were just put in, `target`'s dataset:
    its metadata describes `target` (passes, clean samples, spec hash, statistics), each entry of
    `records` says where passes came from (their per-frame times from `timings`), and the folder
    validates."""
    meta["passes"] = {m: list(p) for m, p in target.passes.items()}
    meta["spec_sha256"] = target.sha256()
    for item in swapped:
        m, name = item.split(".")
        if name in CLEAN_SAMPLE_PASSES:
            meta["render"][m]["clean_samples"] = getattr(target.rig, m).clean_samples
        meta["timings_s"]["render"][item] = timings.get(item)
    meta.update(records)
    (dataset / "scene.yaml").write_text(target.to_yaml())
    meta["stats"] = scene_stats(dataset, meta)
    write_json(dataset / "dataset.json", meta)
    validate_dataset(dataset)


def smoke_agreement(dataset: Path, rendered: Path) -> dict[str, Any]:
    """How closely the smoke opacity rendered again (`rendered`) matches the dataset's, per RGB
    frame (``opacity_difference``): the largest and the mean RMS of block means, the largest share
    of its allowance a frame uses (over 1 refuses), and the pixel figures for the record."""
    pf = PASS_FILES[SMOKE_CHECK][0]
    frames = json.loads((dataset / transforms_name("rgb")).read_text())["frames"]
    diffs = [opacity_difference(read_exr_channel(file_path(rendered, pf, f["file_stem"]), "A"),
                                read_exr_channel(file_path(dataset, pf, f["file_stem"]), "A")) for f in frames]
    worst = max(diffs, key=lambda d: d.share_of_allowed)
    return {"pass": ".".join(SMOKE_CHECK), "frames": len(diffs), "block_px": SMOKE_CHECK_BLOCK,
            "max_frame_rms": max(d.block_rms for d in diffs),
            "mean_frame_rms": float(np.mean([d.block_rms for d in diffs])),
            "tolerance_rms": SMOKE_CHECK_RMS, "noise_factor": SMOKE_CHECK_NOISE,
            "max_share_of_allowed": worst.share_of_allowed, "worst_frame_allowed_rms": worst.allowed,
            "max_frame_pixel_rms": max(d.pixel_rms for d in diffs),
            "mean_frame_pixel_rms": float(np.mean([d.pixel_rms for d in diffs]))}


def refresh_ground_truth(dataset: Path, target: SceneSpec, threads: int | None = None, show_progress: bool = True,
                         bake_store: Path | None = None) -> Path:
    """Re-render what `refresh_plan` says and swap it in. Staged beside the dataset
    (`.NAME.refresh/`, resumed after an interruption); the dataset is replaced only once the new
    one validates. With `bake_store`, a pass that needs the smoke keeps its bake there."""
    dataset = Path(dataset).resolve()
    staging = dataset.parent / f".{dataset.name}.refresh"
    if not dataset.exists() and (staging / "old").exists():  # stopped between the two renames
        os.replace(staging / "dataset", dataset)
        shutil.rmtree(staging)
        return dataset
    if not (dataset / "dataset.json").is_file():
        raise GeneratorError(f"{dataset}: no finished dataset to render ground truth into")
    plan = refresh_plan(dataset, target)
    if plan is None:
        raise GeneratorError(f"{dataset / 'scene.yaml'}: the dataset differs from spec {target.name!r} in more "
                             "than ground truth it could render alone (or not at all); regenerate it instead")
    target = without_absent_passes(target)
    started = time.perf_counter()
    meta = json.loads((dataset / "dataset.json").read_text())
    before = rendered_clean_samples(meta)
    checked = plan.needs_smoke and SMOKE_CHECK[1] in meta["passes"].get(SMOKE_CHECK[0], [])
    if plan.needs_smoke and not checked:
        log.warning("%s: no RGB smoke opacity to check the new bake against; the added passes are not checked",
                    dataset.name)
    rendered = staging / "render"
    log.info("%s: rendering %s (clean samples %s, were %s)%s", dataset.name, ", ".join(plan.swapped()),
             {m: getattr(target.rig, m).clean_samples for m in MODALITIES}, before,
             f", with {'.'.join(SMOKE_CHECK)} to check the bake" if checked else "")
    resumed = (rendered / "dataset.json").is_file()
    if not resumed:
        generate(replace(target, passes=plan.render_passes(checked)), rendered, threads=threads, force=True,
                 show_progress=show_progress, bake_store=bake_store)
    else:
        log.info("%s: the render kept by an earlier attempt is checked and swapped in", dataset.name)
    new_meta = json.loads((rendered / "dataset.json").read_text())
    check = smoke_agreement(dataset, rendered) if checked else None
    if check is not None and check["max_share_of_allowed"] > 1.0:
        raise GeneratorError(f"{dataset / 'dataset.json'}: the simulation baked again is not the dataset's smoke "
                             f"(RGB smoke opacity over {SMOKE_CHECK_BLOCK}-pixel blocks differs in a frame by "
                             f"{check['max_share_of_allowed']:.2f} times what it may: more than {SMOKE_CHECK_RMS} RMS "
                             f"and more than {SMOKE_CHECK_NOISE:g} times what pixel noise leaves over a block); "
                             "regenerate the dataset instead")
    fresh = staging / "dataset"
    if fresh.exists():
        shutil.rmtree(fresh)
    shutil.copytree(dataset, fresh)
    copy_passes(rendered, fresh, plan.swapped(), "regenerate the dataset instead")
    common = {"code_sha256": render_code_digest(),
              "versions": {**versions(), "blender": new_meta["versions"]["blender"]},
              "seconds": round(time.perf_counter() - started, 1), "render_seconds": new_meta["timings_s"]["total"],
              "render_kept_from_an_earlier_attempt": resumed}
    records: dict[str, dict[str, Any]] = {}
    if plan.resampled:
        records["clean_refresh"] = {
            "passes": [f"{m}.{p}" for m, ps in plan.resampled.items() for p in ps], "clean_samples_before": before,
            "clean_samples": {m: getattr(target.rig, m).clean_samples for m in plan.resampled}, **common,
            "note": "only the passes rendered at the clean samples were rendered again; every other file is the "
                    "original dataset's"}
    if plan.added:
        records["passes_added"] = {
            "passes": [f"{m}.{p}" for m, ps in plan.added.items() for p in ps], "bake": new_meta.get("bake"),
            "smoke_check": check, **common,
            "note": "ground-truth passes rendered after the dataset was made; every file a trainer reads is the "
                    "original dataset's"}
    finish_swap(fresh, meta, target, new_meta["timings_s"]["render"], plan.swapped(), records)
    old = staging / "old"
    os.replace(dataset, old)
    os.replace(fresh, dataset)
    shutil.rmtree(staging)
    log.info("%s: %s rendered again in %.0f s", dataset.name, ", ".join(plan.swapped()), time.perf_counter() - started)
    return dataset
