"""One Stage 2 per geometry: runs of a plan that differ only in Stage 3 or in Stage 1's masks
(Table 2's ablations and "Full, estimated Stage 1" beside Full, on the same scene, seed, dataset
and trainer code) take the finished Stage-2 checkpoint of the first of them instead of training
the same Stage 2 again.

A run whose Stage 3 starts from two surfaces also trains an RGB Stage 2 after the thermal one
(``stage2_rgb.pt``, ``stage3.surface_init=by-smoke-colour``); a taker gets that one too when the
donor has finished it, or trains it itself (the same bytes: its random streams are seeded from
the run seed, not left by the thermal Stage 2). Two candidates whose RGB Stage 2 differs from
Full's but not from each other's take it from the first of them: the second starts last and
prefers the donor that has it.

The trainer keys its Stage-2 checkpoint by the settings Stage 2 depends on
(``TrainConfig.stage2_sha256``), and every stage draws from its own streams, so a run that resumes
from a finished Stage 2 ends with the bytes of one that trained it (tests/test_trainer.py). The
donor's Stage-2 rows of train_log.csv come along, so the taker's logged wall time counts the
Stage 2 it did not train, and its harness record names the donor.

With several workers, two runs of a group started side by side would both train that Stage 2.
So the harness starts every group's first run before any other member (``leaders_first``), and a
member that starts while its group's first run is still in Stage 2 waits for it
(``eval.harness.run_task``). ``benchmarks/stage2_sharing.py`` measures what this saves on a
table's finished runs.
"""
from __future__ import annotations

import shutil
from pathlib import Path

from contracts.atomic import atomic_path, write_rows_csv
from contracts.train_log import read_train_log
from eval.runs import RunSpec
from smokeseer.config import make_config


def stage2_sha_of(mode: str, profile: str, seed: int, overrides: dict) -> str:
    """The trainer's key of a run's Stage-2 checkpoint."""
    return make_config(mode, profile, seed, overrides).stage2_sha256()


def rgb_stage2_sha_of(profile: str, seed: int, overrides: dict) -> str:
    """The trainer's key of a run's RGB Stage 2 (``stage2_rgb``, trained where Stage 3 starts
    from two surfaces): RGB-only's Stage-2 key under the run's settings."""
    return stage2_sha_of("rgb-only", profile, seed, overrides)


def stage2_sha(spec: RunSpec) -> str:
    return stage2_sha_of(spec.mode, spec.profile, spec.seed, dict(spec.overrides))


def rgb_stage2_sha(spec: RunSpec) -> str:
    return rgb_stage2_sha_of(spec.profile, spec.seed, dict(spec.overrides))


def stage2_key(spec: RunSpec) -> tuple[str, ...]:
    """Runs with equal keys train the same Stage 2 (same data, seed, code and Stage-2 settings)."""
    return (spec.scene, str(spec.seed), spec.dataset_hash, spec.code, stage2_sha(spec))


def stage2_groups(specs: list[RunSpec], out: Path) -> dict[str, list[str]]:
    """For each run folder, the folders of the plan's runs with the same Stage 2 (itself
    included), in plan order: the first trains it, the others may take it."""
    groups: dict[tuple[str, ...], list[str]] = {}
    of: dict[str, list[str]] = {}
    for spec in specs:
        run_dir = str(spec.run_dir(out).resolve())
        of[run_dir] = groups.setdefault(stage2_key(spec), [])
        of[run_dir].append(run_dir)
    return of


def stage2_donors(groups: dict[str, list[str]]) -> dict[str, list[str]]:
    """For each run folder, the other folders of its Stage-2 group, in plan order."""
    return {d: [o for o in group if o != d] for d, group in groups.items()}


def stage2_leaders(groups: dict[str, list[str]]) -> dict[str, str]:
    """For each run folder after the first of its Stage-2 group (plan order), that first folder."""
    return {d: group[0] for d, group in groups.items() if group[0] != d}


def rgb_stage2_key(spec: RunSpec) -> tuple[str, ...]:
    """Runs with equal keys train the same RGB Stage 2 (``stage2_rgb.pt``), whatever their thermal one."""
    return (spec.scene, str(spec.seed), spec.dataset_hash, spec.code, rgb_stage2_sha(spec))


def leaders_first(specs: list[RunSpec], out: Path, groups: dict[str, list[str]]) -> list[RunSpec]:
    """Plan order with every run that can take a Stage 2 moved behind all the runs that train
    one, so that with several workers a taker starts after its donor has (and, but for the last
    few, has finished Stage 2): started side by side, both would train it. Among the takers, one
    whose RGB Stage 2 no group leader trains but an earlier taker does (two candidates that differ
    in Stage 3 only) goes behind the others, so that it finds that RGB Stage 2 finished."""
    leaders = stage2_leaders(groups)
    taking = [str(s.run_dir(out).resolve()) in leaders for s in specs]
    keys = [rgb_stage2_key(s) for s in specs]
    trained_first = {key for key, takes in zip(keys, taking) if not takes}
    seen: set[tuple[str, ...]] = set()
    behind: list[bool] = []
    for key, takes in zip(keys, taking):
        behind.append(takes and key in seen and key not in trained_first)
        seen.add(key)
    return [specs[i] for i in sorted(range(len(specs)), key=lambda i: (taking[i], behind[i]))]


def stage2_done(run_dir: Path, stage2_sha: str, checkpoint: str = "stage2") -> bool:
    """Whether the folder holds a finished Stage-2 checkpoint (``checkpoint``.pt) of these settings."""
    import torch

    source = run_dir / "checkpoints" / f"{checkpoint}.pt"
    if not source.is_file():
        return False
    try:
        payload = torch.load(source, map_location="cpu", weights_only=False)
    except Exception:  # being written: not finished yet
        return False
    return bool(payload.get("done")) and payload.get("config_sha256") == stage2_sha


def take_finished_stage2(run_dir: Path, donors: list[str], stage2_sha: str, rgb_sha: str = "") -> str:
    """Copy a donor's finished Stage-2 checkpoint (and its Stage-2 log rows) into a run folder that
    has not started, with the donor's finished RGB Stage 2 (``rgb_sha``) where it has one (it writes
    no log rows); returns the donor's folder, or "" when none has one yet. The first donor in
    ``donors`` order that has both is taken, else the first that has the thermal one."""
    checkpoint = run_dir / "checkpoints" / "stage2.pt"
    if checkpoint.exists() or (run_dir / "train_log.csv").exists():
        return ""
    ready = [d for d in map(Path, donors) if (d / "train_log.csv").is_file() and stage2_done(d, stage2_sha)]
    has_rgb = {d: bool(rgb_sha) and stage2_done(d, rgb_sha, "stage2_rgb") for d in ready}
    ready.sort(key=lambda d: not has_rgb[d])
    for donor in ready:
        try:
            rows = [r for r in read_train_log(donor / "train_log.csv") if r["stage"] == "2"]
        except Exception:  # damaged: this donor is skipped, the run trains its own Stage 2
            continue
        if not rows:
            continue
        with atomic_path(checkpoint) as tmp:
            shutil.copyfile(donor / "checkpoints" / "stage2.pt", tmp)
        if has_rgb[donor]:
            with atomic_path(run_dir / "checkpoints" / "stage2_rgb.pt") as tmp:
                shutil.copyfile(donor / "checkpoints" / "stage2_rgb.pt", tmp)
        write_rows_csv(run_dir / "train_log.csv", rows)
        return str(donor)
    return ""
