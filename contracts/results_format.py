"""Validate a RUN_DIR against docs/results-format.md (the trainer ↔ tables contract)."""
from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

RESULTS_FORMAT = "smokeseer-synth-results"
RESULTS_FORMAT_VERSION = 1
METRIC_KEYS = ("psnr", "ssim", "lpips", "lpips_status", "psnr_input", "depth_absrel", "depth_rmse", "mask_iou")
SHADOWED_METRIC_KEYS = ("psnr_shadowed", "ssim_shadowed", "psnr_input_shadowed")
"""Scores against the dataset's shadowed ground truth (``rgb.shadowed``): null without it, and absent
from runs written before it existed."""
SURFACE_DIAGNOSTIC_KEYS = ("colour_bias_smoky", "smoky_pixels", "colour_bias_smoky_max", "surface_alpha_under_0_9")
"""metrics.json ``surface_diagnostics`` (smokeseer/evaluation/scoring.py): how the de-smoked surface errs."""
SURFACE_PSNR_KEYS = ("psnr_surface_pixels", "psnr_surface_pixels_on_black")
"""``surface_diagnostics``' PSNRs on the pixels with a surface in the clean depth, with the environment
and on black; runs of trainer 5e0f3ef6 recorded ``psnr_black_background`` (every pixel, on black) instead."""
SURFACE_PSNR_KEYS_BEFORE = ("psnr_black_background",)
TOP_KEYS = ("format", "format_version", "scene", "dataset", "method", "profile", "seed", "status", "provenance")
PROVENANCE_KEYS = ("commit", "version", "source_digest", "threads", "machine")
RENDER_DIRS = ("composite", "surface", "smoke")
STAGE3_PLAN_KEYS = ("smoke_colour", "mask_floor", "depth_prior", "depth_camera", "loss_weights", "dropped")
"""metrics.json ``stages.stage3_plan``: what Stage 3 trained with (smokeseer/train/plan.py writes it)."""


@dataclass(frozen=True)
class RunWarning:
    """metrics.json ``warnings[i]``: what the trainer found wrong with its input or its optimisation, as
    a machine-readable code, a sentence, and the statistic that crossed its limit."""

    code: str
    message: str
    statistic: str
    value: float
    limit: float

    def record(self) -> dict[str, Any]:
        return asdict(self)

    def line(self) -> str:
        """The log line."""
        return f"warning {self.code}: {self.message}"


WARNING_KEYS = tuple(f.name for f in fields(RunWarning))
DIVERGED_KEYS = ("stage", "checkpoint", "iteration", "loss", "best", "best_iteration", "rise", "factor")
"""metrics.json ``diverged``: where a stage's loss ran away (status ``diverged``)."""


class ResultsFormatError(ValueError):
    """A run directory that breaks the results contract; the message names the file and field."""


def _finite_or_null(path: Path, key: str, value: Any) -> None:
    if value is None:
        return
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ResultsFormatError(f"{path}: field {key!r} must be a finite number or null, got {value!r}")


def read_metrics(run_dir: Path) -> dict[str, Any]:
    """metrics.json of a run folder, checked field by field (what the tables read)."""
    run_dir = Path(run_dir)
    mpath = run_dir / "metrics.json"
    if not mpath.is_file():
        raise ResultsFormatError(f"{mpath}: missing file")
    try:
        doc = json.loads(mpath.read_text(), parse_constant=lambda c: float(c))
    except json.JSONDecodeError as exc:
        raise ResultsFormatError(f"{mpath}: not valid JSON ({exc})") from exc
    for key in TOP_KEYS:
        if key not in doc:
            raise ResultsFormatError(f"{mpath}: missing field {key!r}")
    if doc["format"] != RESULTS_FORMAT or doc["format_version"] != RESULTS_FORMAT_VERSION:
        raise ResultsFormatError(f"{mpath}: field 'format'/'format_version' is not smokeseer-synth-results v1")
    for key in PROVENANCE_KEYS:
        if not isinstance(doc["provenance"], dict) or key not in doc["provenance"]:
            raise ResultsFormatError(f"{mpath}: missing field 'provenance.{key}'")
    warnings(doc, mpath)
    if doc["status"] in ("failed", "diverged"):
        if not doc.get("error"):
            raise ResultsFormatError(f"{mpath}: a {doc['status']} run needs field 'error'")
        if "metrics" in doc:
            raise ResultsFormatError(f"{mpath}: a {doc['status']} run must not carry 'metrics'")
        if doc["status"] == "diverged":
            diverged = doc.get("diverged")
            for key in DIVERGED_KEYS:
                if not isinstance(diverged, dict) or key not in diverged:
                    raise ResultsFormatError(f"{mpath}: missing field 'diverged.{key}'")
        return doc
    if doc["status"] != "ok":
        raise ResultsFormatError(f"{mpath}: field 'status' must be 'ok', 'failed' or 'diverged', got {doc['status']!r}")
    metrics = doc.get("metrics")
    if not isinstance(metrics, dict):
        raise ResultsFormatError(f"{mpath}: missing field 'metrics'")
    for key in METRIC_KEYS:
        if key not in metrics:
            raise ResultsFormatError(f"{mpath}: missing field 'metrics.{key}'")
        if key != "lpips_status":
            _finite_or_null(mpath, f"metrics.{key}", metrics[key])
    for key in SHADOWED_METRIC_KEYS:
        _finite_or_null(mpath, f"metrics.{key}", metrics.get(key))
    for i, entry in enumerate(doc.get("per_image", [])):
        for key, value in entry.items():
            if key != "file_stem":
                _finite_or_null(mpath, f"per_image[{i}].{key}", value)
    for key in ("wall_time_s", "versions", "config_sha256"):
        if key not in doc:
            raise ResultsFormatError(f"{mpath}: missing field {key!r}")
    surface_diagnostics(doc, mpath)
    stage3_plan(doc, mpath)
    return doc


def _object_with(found: Any, field: str, keys: tuple[str, ...], mpath: Path) -> None:
    """Refuse, naming the field, a record that is not an object or lacks one of ``keys``."""
    if not isinstance(found, dict):
        raise ResultsFormatError(f"{mpath}: field '{field}' must be an object")
    for key in keys:
        if key not in found:
            raise ResultsFormatError(f"{mpath}: missing field '{field}.{key}'")


def surface_diagnostics(doc: dict[str, Any], mpath: Path) -> dict[str, Any] | None:
    """``surface_diagnostics`` of a metrics.json, checked; None for runs written before it was
    recorded and for runs without clean ground truth."""
    found = doc.get("surface_diagnostics")
    if found is None:
        return None
    _object_with(found, "surface_diagnostics", SURFACE_DIAGNOSTIC_KEYS, mpath)
    bias = found["colour_bias_smoky"]
    if bias is not None and (not isinstance(bias, list) or len(bias) != 3):
        raise ResultsFormatError(f"{mpath}: field 'surface_diagnostics.colour_bias_smoky' must be 3 numbers or null")
    for i, value in enumerate(bias or []):
        _finite_or_null(mpath, f"surface_diagnostics.colour_bias_smoky[{i}]", value)
    psnr_keys = SURFACE_PSNR_KEYS_BEFORE if SURFACE_PSNR_KEYS_BEFORE[0] in found else SURFACE_PSNR_KEYS
    _object_with(found, "surface_diagnostics", psnr_keys, mpath)
    for key in ("colour_bias_smoky_max", "surface_alpha_under_0_9", *psnr_keys):
        _finite_or_null(mpath, f"surface_diagnostics.{key}", found[key])
    return found


def warnings(doc: dict[str, Any], mpath: Path) -> list[dict[str, Any]]:
    """``warnings`` of a metrics.json, checked; empty for runs written before it was recorded."""
    found = doc.get("warnings", [])
    if not isinstance(found, list):
        raise ResultsFormatError(f"{mpath}: field 'warnings' must be a list")
    for i, entry in enumerate(found):
        for key in WARNING_KEYS:
            if not isinstance(entry, dict) or key not in entry:
                raise ResultsFormatError(f"{mpath}: missing field 'warnings[{i}].{key}'")
        for key in ("value", "limit"):
            _finite_or_null(mpath, f"warnings[{i}].{key}", entry[key])
    return found


def stage3_plan(doc: dict[str, Any], mpath: Path) -> dict[str, Any] | None:
    """``stages.stage3_plan`` of a metrics.json, checked; None for a run without Stage 3 and for
    runs written before the plan was recorded (their readers fall back on ``stages.smoke_colour``)."""
    plan = (doc.get("stages") or {}).get("stage3_plan")
    if plan is None:
        return None
    _object_with(plan, "stages.stage3_plan", STAGE3_PLAN_KEYS, mpath)
    for key in ("loss_weights", "dropped"):
        if not isinstance(plan[key], dict):
            raise ResultsFormatError(f"{mpath}: field 'stages.stage3_plan.{key}' must be an object")
    for term, weight in plan["loss_weights"].items():
        _finite_or_null(mpath, f"stages.stage3_plan.loss_weights.{term}", weight)
    return plan


def validate_run_dir(run_dir: Path) -> dict[str, Any]:
    """Check metrics.json and, for an ``ok`` run, every output file; returns metrics.json."""
    run_dir = Path(run_dir)
    doc = read_metrics(run_dir)
    if doc["status"] != "ok":
        return doc
    for name in ("config.json", "train_log.csv", "ply/surface.ply"):
        if not (run_dir / name).is_file():
            raise ResultsFormatError(f"{run_dir / name}: missing file")
    with (run_dir / "train_log.csv").open() as fh:
        header = next(csv.reader(fh), [])
    for col in ("iteration", "stage", "wall_s", "test_psnr"):
        if col not in header:
            raise ResultsFormatError(f"{run_dir / 'train_log.csv'}: missing column {col!r}")
    stems = [e["file_stem"] for e in doc.get("per_image", [])]
    for sub in RENDER_DIRS:
        for stem in stems:
            p = run_dir / "renders" / sub / f"{stem}.png"
            if not p.is_file():
                raise ResultsFormatError(f"{p}: missing file")
    if not list((run_dir / "checkpoints").glob("stage*.pt")):
        raise ResultsFormatError(f"{run_dir / 'checkpoints'}: no stageN.pt checkpoint")
    return doc
