"""The settings of one ``regenerate-tables`` invocation, and what became of each dataset.

Apart from the harness (eval/harness.py) so that the report and the other writers can take
them without importing the harness that calls them.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from eval.runs import ABLATIONS, CANDIDATES, METHODS
from smokeseer.config import LPIPS_NETS, PROFILES, make_config
from smokeseer.train.plan import depth_term_on


def default_workers() -> int:
    """Half the cores: each training run uses two torch threads."""
    return max(1, (os.cpu_count() or 1) // 2)


def default_ablations(profile: str, train_overrides: dict[str, Any]) -> list[str]:
    """Table 2's rows: each prior switched off, and for the depth term the row that differs from
    this profile's Full: "w/o depth" where Full has the term, "with depth (Stage-2 prior)" where it
    has none (the standard profile: docs/method.md), so no row repeats Full's run."""
    has_depth = depth_term_on(make_config("full", profile, overrides=train_overrides))
    skip = "stage2-depth" if has_depth else "no-depth"
    return [key for key in ABLATIONS if key != skip]


@dataclass
class HarnessConfig:
    """Every setting of one `regenerate-tables` invocation (all of it goes in report.md)."""

    out: Path
    scenes: list[str]
    methods: list[str] = field(default_factory=lambda: list(METHODS))
    ablations: list[str] | None = None
    """None: ``default_ablations`` of the profile and overrides."""
    candidates: list[str] = field(default_factory=list)
    """Rule candidates (``eval.runs.CANDIDATES``) run beside Full."""
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    profile: str = "quick"
    train_overrides: dict[str, Any] = field(default_factory=dict)
    gen_overrides: dict[str, Any] = field(default_factory=dict)
    datasets: dict[str, Path] = field(default_factory=dict)
    dataset_seed: int = 0
    dehazer: str = "dcp"
    workers: int = field(default_factory=default_workers)
    scheduler: str | None = None
    lpips_net: str = "alex"
    lpips_weights: str | None = None
    lpips_heads: str | None = None
    finished_only: bool = False
    """Table the runs already finished in ``out``; generate, dehaze and train nothing (the rest are pending)."""
    trainer_digest: str = ""
    """With ``finished_only``: the code digest of the trainer whose runs are tabled, an earlier
    one's whose runs ``out`` keeps; "" for today's trainer (the digest is part of every run's key)."""
    device: str = "cpu"
    """Torch device the runs train on. Like the thread count, it is not part of a run's cache key
    (the method and settings are the same; the float rounding differs): each run records it in
    harness.json and its config.json, and the report lists it."""

    def __post_init__(self) -> None:
        if self.ablations is None:
            self.ablations = default_ablations(self.profile, self.train_overrides)

    def validate(self) -> None:
        if not self.scenes:
            raise ValueError("scenes: at least one scene is needed")
        if len(set(self.scenes)) != len(self.scenes):
            raise ValueError(f"scenes: duplicates in {self.scenes}")
        for m in self.methods:
            if m not in METHODS:
                raise ValueError(f"methods: unknown {m!r}, choose from {', '.join(METHODS)}")
        for a in self.ablations:
            if a not in ABLATIONS:
                raise ValueError(f"ablations: unknown {a!r}, choose from {', '.join(ABLATIONS)}")
        for c in self.candidates:
            if c not in CANDIDATES:
                raise ValueError(f"candidates: unknown {c!r}, choose from {', '.join(CANDIDATES)}")
        if not self.methods and not self.ablations and not self.candidates:
            raise ValueError("methods: nothing to run (no methods and no ablations)")
        if not self.seeds or any(s < 0 for s in self.seeds) or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds: need distinct non-negative seeds, got {self.seeds}")
        if self.profile not in PROFILES:
            raise ValueError(f"profile: must be one of {', '.join(PROFILES)}, got {self.profile!r}")
        if self.workers < 1:
            raise ValueError(f"workers: must be >= 1, got {self.workers}")
        if self.device.split(":")[0] not in ("cpu", "cuda"):
            raise ValueError(f"device: must be cpu, cuda or cuda:N, got {self.device!r}")
        if "device" in self.train_overrides:
            raise ValueError("train_overrides: 'device' is set with --device (recorded per run, not keyed), "
                             "not with --set device=...")
        if self.device != "cpu" and not self.finished_only:
            import torch

            if not torch.cuda.is_available():
                raise ValueError(f"device: {self.device} asked for, but torch {torch.__version__} sees no CUDA device")
        if self.trainer_digest and not self.finished_only:
            raise ValueError("digest: only with --finished-only (a run trains under today's trainer's digest)")
        if self.lpips_net not in LPIPS_NETS:
            raise ValueError(f"lpips_net: must be one of {', '.join(LPIPS_NETS)}, got {self.lpips_net!r}")
        for scene, path in self.datasets.items():
            if not (Path(path) / "dataset.json").is_file():
                raise ValueError(f"datasets: {scene}={path} has no dataset.json")

    def variants(self) -> list[str]:
        """Methods, ablations and candidates, plus Full as their reference when it is not a method."""
        keys = list(self.methods) + list(self.ablations) + list(self.candidates)
        if (self.ablations or self.candidates) and "full" not in keys:
            keys.append("full")
        return keys

    def run_overrides(self) -> dict[str, Any]:
        """Trainer overrides of every run: the user's, plus the LPIPS settings (the trainer is the
        one LPIPS scorer, at its own resolution, so they belong to the run's cache key)."""
        ov = dict(self.train_overrides)
        if self.lpips_net != "alex":
            ov["lpips_net"] = self.lpips_net
        if self.lpips_weights:
            ov["lpips_weights"] = str(self.lpips_weights)
        if self.lpips_heads:
            ov["lpips_heads"] = str(self.lpips_heads)
        return ov


@dataclass
class DatasetOutcome:
    scene: str
    kind: str  # "generated", "provided" or "dehazed:<name>"
    path: str
    hash: str
    status: str = "ok"
    error: str = ""
    wall_time_s: float = 0.0
    cached: bool = False
