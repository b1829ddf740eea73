"""The smoke-free ceiling of a scene: the same trainer and budget fed the clean renders.

A de-smoking method's test PSNR is bounded by what the reconstruction reaches with no smoke
at all. Where that bound is far above the smoky input (thin smoke), a method under the input
loses in its handling of the smoke, not in the budget; where the bound is near the input,
"beat the input" is out of reach at that budget whatever the method does.

The derived dataset is the original with its RGB smoky frames replaced by the clean ones
(links, no copies), the RGB smoke passes dropped and ``smoke.present`` false, so the trainer
fits no smoke Gaussians; its dataset.json says all this under ``derived_from``.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from contracts.atomic import write_json
from contracts.dataset_format import PASS_FILES, validate_dataset
from contracts.results_format import read_metrics

SMOKY_RGB = PASS_FILES[("rgb", "smoky")][0].folder
CLEAN_RGB = PASS_FILES[("rgb", "clean")][0].folder
DROPPED = PASS_FILES[("rgb", "smoke_alpha")]


def derive_clean_dataset(src: Path, dst: Path) -> Path:
    """Write ``dst`` as ``src`` with its clean RGB frames in place of the smoky ones (kept if
    ``dst`` is already a finished derived dataset). Written in a staging folder and renamed,
    so an interrupted call leaves no half dataset."""
    if (dst / "dataset.json").is_file():
        return dst
    meta = validate_dataset(src, check_images=False)
    if "clean" not in meta["passes"].get("rgb", []):
        raise ValueError(f"{src / 'dataset.json'}: field 'passes.rgb' has no 'clean' pass to train on")
    src = src.resolve()
    skip = {SMOKY_RGB, *(pf.folder for pf in DROPPED)}
    staging = dst.with_name(f".{dst.name}.staging")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    for entry in src.iterdir():
        if entry.name not in ("dataset.json", "rgb"):
            os.symlink(entry, staging / entry.name)
    (staging / "rgb").mkdir()
    for entry in (src / "rgb").iterdir():
        if f"rgb/{entry.name}" not in skip:
            os.symlink(entry, staging / "rgb" / entry.name)
    os.symlink(src / CLEAN_RGB, staging / SMOKY_RGB)
    meta["passes"]["rgb"] = [p for p in meta["passes"]["rgb"] if p != "smoke_alpha"]
    meta.setdefault("smoke", {})["present"] = False
    meta["derived_from"] = {
        "dataset": str(src), "spec_sha256": meta.get("spec_sha256"),
        "change": f"{SMOKY_RGB} links to {CLEAN_RGB}; the RGB smoke_alpha pass is dropped and smoke.present "
                  "is false: the smoke-free ceiling of eval/clean_ceiling.py"}
    write_json(staging / "dataset.json", meta)
    validate_dataset(staging)
    os.replace(staging, dst)
    return dst


def smoky_input_psnr(scene: str, profile: str, table_runs: Path) -> tuple[float | None, float | None]:
    """The smoky input's (test, validation) PSNR from any finished table run of the scene at this
    profile (the input does not depend on method or seed); (None, None) where there is none. A
    metrics.json that breaks the results contract raises ResultsFormatError naming it."""
    for path in sorted(table_runs.glob(f"{scene}/*/seed*/metrics.json")):
        doc = read_metrics(path.parent)
        if doc["profile"] == profile and doc["status"] == "ok":
            return doc["metrics"]["psnr_input"], (doc.get("validation") or {}).get("psnr_input")
    return None, None
