"""Figures read from run folders: iterations per second per stage from a train_log.csv, and the
committed CPU runs a GPU run's test PSNR is compared with."""
from __future__ import annotations

import json
import statistics
from dataclasses import dataclass
from pathlib import Path

from contracts.train_log import read_train_log


def stage_rates(log: Path, last_iteration: int | None = None) -> dict[str, float]:
    """Stage -> iterations per second between the stage's first and last logged row (up to
    ``last_iteration`` when given), from the log's cumulative ``wall_s``. The time before the
    first row (set-up, the first ``log_every`` iterations) is left out."""
    by_stage: dict[str, list[tuple[int, float]]] = {}
    for row in read_train_log(log):
        it = int(row["iteration"])
        if last_iteration is None or it <= last_iteration:
            by_stage.setdefault(row["stage"], []).append((it, float(row["wall_s"])))
    rates = {}
    for stage, rows in by_stage.items():
        (i0, w0), (i1, w1) = rows[0], rows[-1]
        if i1 > i0 and w1 > w0:
            rates[stage] = (i1 - i0) / (w1 - w0)
    return rates


def last_iterations(log: Path) -> dict[str, int]:
    """Stage -> the last iteration the log reached."""
    out: dict[str, int] = {}
    for row in read_train_log(log):
        out[row["stage"]] = max(out.get(row["stage"], 0), int(row["iteration"]))
    return out


@dataclass
class CpuReference:
    """The committed CPU runs of one trainer version: seed 0's PSNR and the spread over seeds."""

    runs_folder: str
    source_digest: str
    seeds: list[int]
    psnrs: list[float]
    seed0_psnr: float
    seed0_run: str

    @property
    def spread_db(self) -> float:
        return max(self.psnrs) - min(self.psnrs)

    def to_dict(self) -> dict:
        return {"runs_folder": self.runs_folder, "source_digest": self.source_digest, "seeds": self.seeds,
                "psnrs": self.psnrs, "seed0_psnr": self.seed0_psnr, "seed0_run": self.seed0_run,
                "spread_db": self.spread_db, "std_db": statistics.pstdev(self.psnrs)}


def cpu_reference(runs: Path, profile: str, prefer: tuple[str, ...] = ()) -> CpuReference:
    """Among the finished CPU runs under ``runs`` (one folder per seed, as regenerate-tables
    writes them) at ``profile``: the trainer version named in ``prefer`` where it has a seed-0 run
    (the GPU run's own version), else the one with a seed-0 run and the most seeds. ``prefer``
    may hold source digests and trainer-source fingerprints (``sources_sha256`` in harness.json):
    the digest differs between Python versions, so a node whose Python is not the CPU runs' finds
    its version by the fingerprint. Raises ValueError naming the folder when there is none."""
    groups: dict[str, dict[int, tuple[float, str]]] = {}
    names: dict[str, set[str]] = {}
    for metrics_path in sorted(runs.glob("*/metrics.json")):
        doc = json.loads(metrics_path.read_text())
        config = json.loads((metrics_path.parent / "config.json").read_text())
        if doc.get("status") != "ok" or doc.get("profile") != profile or config.get("device") != "cpu":
            continue
        digest = doc["provenance"]["source_digest"]
        groups.setdefault(digest, {}).setdefault(int(doc["seed"]), (float(doc["metrics"]["psnr"]),
                                                                     metrics_path.parent.name))
        harness = metrics_path.parent / "harness.json"
        sources = json.loads(harness.read_text()).get("sources_sha256") if harness.is_file() else None
        names.setdefault(digest, {digest}).update([sources] if sources else [])
    usable = {d: seeds for d, seeds in groups.items() if 0 in seeds}
    if not usable:
        raise ValueError(f"{runs}: no finished CPU run of seed 0 at profile {profile}")
    own = [d for d in sorted(usable) if names[d] & set(prefer)]
    digest = own[0] if own else max(sorted(usable), key=lambda d: len(usable[d]))
    seeds = usable[digest]
    order = sorted(seeds)
    return CpuReference(str(runs), digest, order, [seeds[s][0] for s in order], seeds[0][0], seeds[0][1])


def psnr_verdict(gpu_psnr: float, ref: CpuReference) -> str:
    """One sentence: is the GPU run's PSNR within the CPU seeds' span of seed 0's?"""
    gap = gpu_psnr - ref.seed0_psnr
    inside = abs(gap) <= ref.spread_db
    return (f"GPU test PSNR {gpu_psnr:.2f} dB, {gap:+.2f} dB from the CPU seed-0 run: "
            f"{'within' if inside else 'outside'} the CPU seeds' span of {ref.spread_db:.2f} dB.")
