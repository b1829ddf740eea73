"""One Stage 2 per geometry: runs of a plan that differ only in Stage 3 (Table 2's ablations beside
Full, on the same scene, seed, dataset and trainer code) take the finished Stage-2 checkpoint of
the first of them instead of training the same Stage 2 again.

The trainer keys its Stage-2 checkpoint by the settings Stage 2 depends on
(``TrainConfig.stage2_sha256``) and stores the run's RNG state in it, so a run that resumes from
a finished Stage 2 ends with the bytes of one that trained it (tests/test_trainer.py). The
donor's Stage-2 rows of train_log.csv come along, so the taker's logged wall time counts the
Stage 2 it did not train, and its harness record names the donor.
"""
from __future__ import annotations

import shutil
from pathlib import Path

from contracts.atomic import atomic_path, write_rows_csv
from contracts.train_log import read_train_log
from eval.runs import RunSpec
from smokeseer.config import make_config


def stage2_sha(spec: RunSpec) -> str:
    """The trainer's key of the run's Stage-2 checkpoint."""
    return make_config(spec.mode, spec.profile, spec.seed, dict(spec.overrides)).stage2_sha256()


def stage2_key(spec: RunSpec) -> tuple[str, ...]:
    """Runs with equal keys train the same Stage 2 (same data, seed, code and Stage-2 settings)."""
    return (spec.scene, str(spec.seed), spec.dataset_hash, spec.code, stage2_sha(spec))


def stage2_donors(specs: list[RunSpec], out: Path) -> dict[str, list[str]]:
    """For each run folder, the folders of the plan's other runs with the same Stage 2, in plan order."""
    groups: dict[tuple[str, ...], list[str]] = {}
    keys = {}
    for spec in specs:
        run_dir = str(spec.run_dir(out).resolve())
        keys[run_dir] = stage2_key(spec)
        groups.setdefault(keys[run_dir], []).append(run_dir)
    return {d: [o for o in groups[k] if o != d] for d, k in keys.items()}


def take_finished_stage2(run_dir: Path, donors: list[str], stage2_sha: str) -> str:
    """Copy the first donor's finished Stage-2 checkpoint (and its Stage-2 log rows) into a run
    folder that has not started; returns the donor's folder, or "" when none has one yet."""
    import torch

    checkpoint = run_dir / "checkpoints" / "stage2.pt"
    if checkpoint.exists() or (run_dir / "train_log.csv").exists():
        return ""
    for donor in map(Path, donors):
        source = donor / "checkpoints" / "stage2.pt"
        if not source.is_file() or not (donor / "train_log.csv").is_file():
            continue
        try:
            payload = torch.load(source, map_location="cpu", weights_only=False)
            rows = [r for r in read_train_log(donor / "train_log.csv") if r["stage"] == "2"]
        except Exception:  # being written, or damaged: this donor is skipped, the run trains its own Stage 2
            continue
        if not (payload.get("done") and payload.get("config_sha256") == stage2_sha and rows):
            continue
        with atomic_path(checkpoint) as tmp:
            shutil.copyfile(source, tmp)
        write_rows_csv(run_dir / "train_log.csv", rows)
        return str(donor)
    return ""
