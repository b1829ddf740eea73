"""The smoke-free ceiling of a scene: the same trainer and budget fed the clean renders.

A de-smoking method's test PSNR is bounded by what the reconstruction reaches with no smoke
at all. Where that bound is far above the smoky input (thin smoke), a method under the input
loses in its handling of the smoke, not in the budget; where the bound is near the input,
"beat the input" is out of reach at that budget whatever the method does.

The derived dataset is the original with its smoky frames replaced by the clean ones, RGB and
thermal (links, no copies), the smoke passes (smoke opacity, shadowed frames) dropped and
``smoke.present`` false, so the trainer fits no smoke Gaussians; its dataset.json says all this
under ``derived_from``. Both Full and RGB-only train on it: thermal must cost nothing where there
is no smoke to see through.
"""
from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from contracts.atomic import write_json
from contracts.dataset_format import PASS_FILES, SMOKE_ONLY_PASSES, validate_dataset
from contracts.recorded_paths import recorded_path
from contracts.results_format import read_metrics

SWAPPED = {modality: dict(zip((pf.folder for pf in PASS_FILES[(modality, "smoky")]),
                              (pf.folder for pf in PASS_FILES[(modality, "clean")])))
           for modality in ("rgb", "thermal")}
"""Per modality, each smoky pass folder and the clean one linked in its place."""
DROPPED = {pf.folder for (_, name), files in PASS_FILES.items() if name in SMOKE_ONLY_PASSES for pf in files}


def derive_clean_dataset(src: Path, dst: Path) -> Path:
    """Write ``dst`` as ``src`` with its clean frames in place of the smoky ones, RGB and thermal
    (kept if ``dst`` is already a finished derived dataset). Written in a staging folder and
    renamed, so an interrupted call leaves no half dataset."""
    if (dst / "dataset.json").is_file():
        return dst
    meta = validate_dataset(src, check_images=False)
    modalities = [m for m in SWAPPED if m in meta["passes"]]
    for modality in modalities:
        if "clean" not in meta["passes"][modality]:
            raise ValueError(f"{src / 'dataset.json'}: field 'passes.{modality}' has no 'clean' pass to train on")
    src = src.resolve()
    swapped = {smoky: clean for m in modalities for smoky, clean in SWAPPED[m].items()}
    staging = dst.with_name(f".{dst.name}.staging")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    for entry in src.iterdir():
        if entry.name != "dataset.json" and entry.name not in modalities:
            os.symlink(entry, staging / entry.name)
    for modality in modalities:
        (staging / modality).mkdir()
        for entry in (src / modality).iterdir():
            folder = f"{modality}/{entry.name}"
            if folder not in DROPPED:
                os.symlink(src / swapped.get(folder, folder), staging / folder)
        meta["passes"][modality] = [p for p in meta["passes"][modality] if p not in SMOKE_ONLY_PASSES]
    meta.setdefault("smoke", {})["present"] = False
    meta["derived_from"] = {
        "dataset": recorded_path(src), "spec_sha256": meta.get("spec_sha256"),
        "change": "; ".join(f"{smoky} links to {clean}" for smoky, clean in swapped.items())
                  + "; the smoke_alpha and shadowed passes are dropped and smoke.present is false: the smoke-free "
                    "ceiling of eval/clean_ceiling.py"}
    write_json(staging / "dataset.json", meta)
    validate_dataset(staging)
    os.replace(staging, dst)
    return dst


def _finished_run(table_runs: Path, pattern: str, profile: str, digest: str) -> dict | None:
    """metrics.json of the first finished table run matching ``pattern`` at this profile whose
    trainer digest starts with ``digest`` (any, for ""); None where there is none. A metrics.json
    that breaks the results contract raises ResultsFormatError naming it."""
    for path in sorted(table_runs.glob(pattern)):
        doc = read_metrics(path.parent)
        if (doc["profile"] == profile and doc["status"] == "ok"
                and (doc["provenance"]["source_digest"] or "").startswith(digest)):
            return doc
    return None


def smoky_input_psnr(scene: str, profile: str, table_runs: Path, digest: str = "") -> tuple[float | None, float | None]:
    """The smoky input's (test, validation) PSNR from any finished table run of the scene at this
    profile (the input does not depend on method or seed) and, given ``digest``, at that trainer
    digest (runs of other trainers may have been scored against clean frames since re-rendered);
    (None, None) where there is none."""
    doc = _finished_run(table_runs, f"{scene}/*/seed*/metrics.json", profile, digest)
    if doc is None:
        return None, None
    return doc["metrics"]["psnr_input"], (doc.get("validation") or {}).get("psnr_input")


def table_test_metrics(scene: str, variant: str, seed: int, profile: str, digest: str,
                       table_runs: Path) -> dict | None:
    """Test scores (metrics.json ``metrics``: PSNR, SSIM, LPIPS, ...) of the finished table run of
    ``variant`` at this scene, seed, profile and trainer digest (its first 8 hex digits); None
    where the tables have none yet."""
    doc = _finished_run(table_runs, f"{scene}/{variant}/seed{seed}-*/metrics.json", profile, digest)
    return None if doc is None else doc["metrics"]


def headroom_recovered(method: float | None, smoky_input: float | None, ceiling: float) -> float | None:
    """The share of the input-to-ceiling gap a method's PSNR closes: 0 at the smoky input, 1 at
    the clean ceiling; None where the gap is not positive (nothing to recover) or a value is missing."""
    if method is None or smoky_input is None or ceiling - smoky_input <= 0:
        return None
    return (method - smoky_input) / (ceiling - smoky_input)


_ABSENT = object()


def _unlike(folder: Path, doc: dict, digest: str, profile: str, seed: int,
            settings: Mapping[str, Any]) -> list[str]:
    """How the ceiling run in ``folder`` (its metrics.json ``doc``) differs from a run of trainer
    ``digest`` at this profile and seed with these config ``settings`` (dotted keys, a candidate's
    overrides), read from the run's config.json."""
    trainer = doc["provenance"]["source_digest"] or ""
    unlike = [f"trainer {trainer[:8] or 'unknown'}, not {digest[:8]}"] if trainer != digest else []
    unlike += [f"{key} {doc[key]}, not {wanted}"
               for key, wanted in (("profile", profile), ("seed", seed)) if doc[key] != wanted]
    if not settings:
        return unlike
    if not (folder / "config.json").is_file():
        return unlike + ["no config.json to check its settings against"]
    config = json.loads((folder / "config.json").read_text())
    for key, wanted in settings.items():
        value: Any = config
        for part in key.split("."):
            value = value.get(part, _ABSENT) if isinstance(value, dict) else _ABSENT
        if value is _ABSENT or value != wanted:
            unlike.append(f"{key} {'absent' if value is _ABSENT else value}, not {wanted}")
    return unlike


def _beside(run_dir: Path, digest: str, profile: str, seed: int) -> Path:
    """Where a run of another request than ``run_dir``'s trains until it takes that folder's place."""
    return run_dir.with_name(f"{run_dir.name}-{digest[:8]}-{profile}-seed{seed}")


def ceiling_digests(folder: Path) -> list[str]:
    """The trainer code digest of every finished ceiling run in ``folder`` (SCENE/MODE/, and the
    retrains beside them), one per run, for ``eval.finished_runs.pick_digest``."""
    docs = [read_metrics(path.parent) for path in sorted(Path(folder).glob("*/*/metrics.json"))]
    return [d["provenance"]["source_digest"] for d in docs if d["status"] == "ok" and d["provenance"]["source_digest"]]


def finished_ceiling(run_dir: Path, digest: str, profile: str, seed: int,
                     settings: Mapping[str, Any] | None = None) -> dict | None:
    """metrics.json of the finished ceiling run of trainer ``digest`` at this profile and seed (and
    config ``settings``, as ``_unlike`` reads them), in ``run_dir`` or (a retrain finished but not yet
    moved in) beside it; None where there is none. Reads only: for tabling the runs of a named
    trainer without training (``--finished-only``)."""
    for folder in (run_dir, _beside(run_dir, digest, profile, seed)):
        if (folder / "metrics.json").is_file():
            doc = read_metrics(folder)
            if doc["status"] == "ok" and not _unlike(folder, doc, digest, profile, seed, settings or {}):
                return doc
    return None


def ceiling_run(run_dir: Path, digest: str, profile: str, seed: int, train: Callable[[Path], None],
                settings: Mapping[str, Any] | None = None) -> dict:
    """metrics.json of the ceiling run in ``run_dir`` made by trainer ``digest`` at this profile
    and seed (and config ``settings``: a candidate's overrides), training it first where that
    folder holds no such finished run.

    ``train(folder)`` runs the trainer into ``folder``, resuming from its checkpoints. It trains
    beside ``run_dir``, in ``MODE-DIGEST-PROFILE-seedSEED``, so a finished run of another request
    stays in place (and committed) until the new one has finished, and an interrupted retrain
    resumes. The finished folder then takes ``run_dir``'s place by two renames; an interruption
    between them leaves the new run complete beside, and the next call completes the swap."""
    if (run_dir / "metrics.json").is_file():
        doc = read_metrics(run_dir)
        unlike = _unlike(run_dir, doc, digest, profile, seed, settings or {})
        if not unlike:
            print(f"{run_dir}: finished by trainer {digest[:8]} at {profile}, seed {seed}: reused", flush=True)
            return doc
        print(f"{run_dir}: a run of {'; '.join(unlike)}: retraining; "
              "the old run stays until the new one has finished", flush=True)
    fresh = _beside(run_dir, digest, profile, seed)
    if not (fresh / "metrics.json").is_file():
        train(fresh)
    unlike = _unlike(fresh, read_metrics(fresh), digest, profile, seed, settings or {})
    if unlike:
        raise RuntimeError(f"{fresh / 'metrics.json'}: the ceiling run just trained is a run of {'; '.join(unlike)}")
    retired = run_dir.with_name(f".{run_dir.name}.retired")
    shutil.rmtree(retired, ignore_errors=True)
    if run_dir.exists():
        os.replace(run_dir, retired)
    os.replace(fresh, run_dir)
    shutil.rmtree(retired, ignore_errors=True)
    return read_metrics(run_dir)
