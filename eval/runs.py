"""What the tables compare: the methods and ablations, the paper's numbers, and the
records a run leaves behind. Shared by the harness, table and figure writers."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from contracts.recorded_paths import recorded_path


@dataclass(frozen=True)
class Variant:
    """One row of Table 1 or Table 2: a trainer mode, optionally on dehazed frames, with the
    trainer config overrides that set it apart (they enter the run's cache key)."""

    key: str
    label: str
    mode: str
    table: str  # "methods", "ablations" or "candidates"
    paper: dict[str, float]
    dehazer: str | None = None
    note: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)


METHODS: dict[str, Variant] = {
    v.key: v
    for v in (
        Variant("imgdehaze-dcp", "ImgDehaze (DCP) + Deformable 3DGS", "deformable-3dgs", "methods",
                {"psnr": 14.42, "ssim": 0.37, "lpips": 0.318}, dehazer="dcp",
                note="paper's dehazer is ConvIR (weights not available offline); ours is the "
                     "dark channel prior with guided-filter refinement"),
        Variant("rgb-only", "Ours (RGB only)", "rgb-only", "methods",
                {"psnr": 15.08, "ssim": 0.38, "lpips": 0.326}),
        Variant("full", "Ours (Full)", "full", "methods",
                {"psnr": 19.92, "ssim": 0.76, "lpips": 0.247},
                note="Stage 1 (smoke masks, thermal-to-RGB registration) read from the generator's ground truth; "
                     "at the standard profile the mask floor acts where the images say the smoke may reach 0.4"),
        Variant("full-estimated", "Ours (Full, estimated Stage 1)", "full", "methods", {},
                note="Stage 1 estimated from the frames without downloaded weights (trainer setting "
                     "stage1=estimate, docs/real-captures.md); the paper reports no such row",
                overrides={"stage1": "estimate"}),
        Variant("full-from-images", "Ours (Full, Stage 1 from images)", "full", "methods", {},
                note="Stage 1 from the frames alone: masks as in the estimated row, and the poses by structure from "
                     "motion on the RGB frames and the rig for the thermal ones (trainer settings stage1=estimate, "
                     "poses=sfm; docs/real-captures.md); a scene where SfM does not register fails with its reason",
                overrides={"stage1": "estimate", "poses": "sfm"}),
    )
}

ABLATIONS: dict[str, Variant] = {
    v.key: v
    for v in (
        Variant("no-smoke-alpha", "w/o smoke_alpha", "no-smoke-alpha", "ablations", {"psnr": 18.96}),
        Variant("no-smoke-color", "w/o smoke_color", "no-smoke-color", "ablations", {"psnr": 19.02}),
        Variant("no-mono", "w/o mono", "no-mono", "ablations", {"psnr": 19.78}),
        Variant("no-depth", "w/o depth", "no-depth", "ablations", {"psnr": 19.88}),
        Variant("no-mask", "w/o mask", "no-mask", "ablations", {"psnr": 19.82}),
        Variant("stage2-depth", "with depth (Stage-2 prior)", "full", "ablations", {},
                note="Full plus the paper's depth term against Stage 2's thermal depth render (the weight-free prior "
                     "we have); Table 2's depth row where the profile's Full has no depth term",
                overrides={"depth_prior": "thermal-render"}),
    )
}

def _candidate(key: str, label: str, note: str, overrides: dict[str, Any]) -> Variant:
    """A Full run with the ``overrides`` of one rule or setting in question."""
    return Variant(key, label, "full", "candidates", {}, note=note, overrides=overrides)


CANDIDATES: dict[str, Variant] = {
    v.key: v
    for v in (
        _candidate("start-thermal", "Full, Stage 3 from the thermal Stage 2",
                   note="the route's candidate with no RGB Stage 2: Stage 3 starts from the thermal Stage 2 alone, "
                        "as the paper's does (docs/method.md, Decisions, row 13)",
                   overrides={"stage3.surface_init": "thermal"}),
        _candidate("mask-bound", "Full, the mask term pushes to what the images prove",
                   note="the mask term pushes each masked pixel's smoke alpha up to the alpha the smoky frames prove "
                        "there (a clear view's reading, else the lower bound where the haze lines meet), in place of "
                        "the floor at 0.4 where the estimate reaches it (loss.mask_floor_where=estimated-bound; "
                        "docs/method.md, Decisions, rows 16-17)",
                   overrides={"loss.mask_floor_where": "estimated-bound"}),
        _candidate("floor-by-meeting-trust", "Full, the mask floor reads the haze lines' meeting by its weight",
                   note="the estimated mask floor blends its rule with and without the point where the haze lines "
                        "meet, by how far that point is trusted (the trust's line and meeting ramps), in place of "
                        "taking the point wherever a fifth of at least 100 lines meet: food_plate's two float "
                        "setups parted there, 106 lines giving the point and a floor on 49 % of the masked "
                        "pixels, under 100 none and 20 % (loss.mask_floor_meeting=trusted; the rules issue's "
                        "cliffs); Stage 3 only",
                   overrides={"loss.mask_floor_meeting": "trusted"}),
        _candidate("thermal-where-smoky", "Full, the thermal term shapes the surface only under smoke",
                   note="the thermal render term moves each surface Gaussian's position, shape and opacity by the "
                        "share of the RGB training views whose smoke mask covers it, so the coarse thermal frames "
                        "cost nothing where the RGB sees the surface clear (stage3.thermal_surface_grad=smoky-views; "
                        "the surface issue: Full's clean ceiling is 1.2 dB under RGB-only's)",
                   overrides={"stage3.thermal_surface_grad": "smoky-views"}),
        _candidate("thermal-box-filtered", "Full, each thermal pixel integrates its area",
                   note="the Stage-3 thermal term renders each thermal pixel as 2x2 sub-pixels and averages them, as "
                        "the sensor integrates its pixel, so a surface Gaussian sized for the RGB pixels (1.6-3 times "
                        "finer than the thermal's on the committed sets) is no longer dilated to a whole thermal pixel at its full "
                        "opacity (stage3.thermal_supersample=2; the surface issue: Full's clean ceiling is 1.2 dB "
                        "under RGB-only's; on clean plant 2x2 gains 1.66 dB validation and 3x3 1.73, "
                        "docs/experiments/2026-12-06-thermal-pixel-area.md); Stage 3 only, and its thermal render "
                        "costs four times the work",
                   overrides={"stage3.thermal_supersample": 2}),
        _candidate("carve-where-smoky", "Full, the joined start fades what lies in front of the thermal surface on smoke",
                   note="in the joined start no RGB Gaussian is dropped for lying in front of the coarse thermal "
                        "surface; each one's opacity is scaled by 1 - the share of its views that see it there on a "
                        "pixel Stage 1 marks smoke, so a scene without smoke keeps its RGB surface whole "
                        "(stage3.carve_by=depth-and-smoke; clean plant carved 40 % of its RGB Gaussians, and carving "
                        "none gained 0.41 dB, docs/experiments/2026-12-06-thermal-pixel-area.md); Stage 3 only",
                   overrides={"stage3.carve_by": "depth-and-smoke"}),
        _candidate("densify-by-gradient", "Full, a full cap grows the largest gradients",
                   note="every densification (Stage 2, the smoke, the surface refinement) takes the candidates with "
                        "the largest mean gradient when they outnumber the room under its cap, in place of clones "
                        "first in index order (docs/method.md, Decisions, row 7); it changes Stage 2, so it trains "
                        "its own",
                   overrides={"stage2.densify.under_cap": "gradient", "stage3.smoke_densify.under_cap": "gradient",
                              "stage3.surface_densify.under_cap": "gradient"}),
        _candidate("caps-doubled", "Full, twice the surface's Gaussian caps",
                   note="Stage 2 and the surface refinement may grow to twice the standard profile's caps (80k, "
                        "160k): at k = 0 chair fills both before half its stages and stays far under its smoke-free "
                        "input (the surface issue's capacity); it changes Stage 2, so it trains its own, and costs "
                        "time",
                   overrides={"stage2.densify.max_gaussians": 80_000, "stage3.surface_densify.max_gaussians": 160_000}),
        _candidate("motion-planes", "Full, the smoke moved by the plane field",
                   note="the smoke's motion by the factorised space-time plane field in place of the deformation "
                        "network (deform.kind=planes, docs/method.md, Plane field); Stage 3 only",
                   overrides={"deform.kind": "planes"}),
    )
}
"""Rules and settings in question, run beside Full on a drawn set (`regenerate-tables --candidates`) and chosen
on its validation views (`benchmarks/random_set_scores.py --split val --candidates`); a candidate
that holds replaces the profile's rule, and leaves this list."""

VARIANTS: dict[str, Variant] = {**METHODS, **ABLATIONS, **CANDIDATES}


def variant_label(key: str) -> str:
    """The row label of a table variant; an unknown key (an older run folder) stands for itself."""
    return VARIANTS[key].label if key in VARIANTS else key


def config_hash(obj: Any) -> str:
    """SHA-256 of canonical JSON: the cache key of a dataset or run."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


@dataclass(frozen=True)
class RunSpec:
    """Everything that decides one training run; its hash names the cache entry."""

    scene: str
    variant: str
    mode: str
    seed: int
    profile: str
    overrides: dict[str, Any]
    dataset: str  # path of the (possibly dehazed) dataset the run trains on
    dataset_hash: str
    code: str  # contracts.source.code_digest of the trainer entry point and what it imports

    def key(self) -> dict[str, Any]:
        """Hashed fields: the dataset enters by content hash, not by path."""
        d = asdict(self)
        d.pop("dataset")
        return d

    def hash(self) -> str:
        return config_hash(self.key())

    def run_dir(self, out: Path) -> Path:
        return Path(out) / "runs" / self.scene / self.variant / f"seed{self.seed}-{self.hash()[:12]}"


@dataclass
class RunResult:
    """What the harness records for a run, finished or failed (never dropped)."""

    scene: str
    variant: str
    seed: int
    status: str  # "ok", "failed", or "pending" (not trained yet: a --finished-only invocation)
    run_dir: str
    config_hash: str
    dataset: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)
    wall_time_s: float = 0.0
    prep_time_s: float = 0.0  # per-scene preprocessing charged to the method (dehazing)
    error: str = ""
    cached: bool = False
    logged_before_s: float = 0.0
    """Wall seconds already in the run's train_log.csv when its last attempt started (earlier
    attempts it resumed from, or the Stage 2 taken from ``stage2_from``); part of wall_time_s."""
    stage2_from: str = ""
    """The run folder whose finished Stage 2 this run took (eval/shared_stage2.py), or ""."""
    same_as: str = ""
    """The variant whose finished run stands for this one, because this one would train exactly like
    it (eval/twins.py; ``run_dir`` is then that run's folder), or ""."""
    same_as_reason: str = ""
    device: str = "cpu"
    """The torch device it trained on (not part of the cache key; see HarnessConfig.device)."""
    code_digest: str = ""
    """The trainer code digest in its cache key (RunSpec.code); "" in records older than the field."""
    sources_sha256: str = ""
    """eval.sources.sources_sha256 of the trainer where it trained: unlike the digest, independent
    of the Python version, so a run made under another Python can be adopted (eval/adopt.py)."""
    adopted_from: str = ""
    """Where a run trained under another key came from, and what was checked (eval/adopt.py), or ""."""
    float_setup: str = ""
    """What set its float rounding where it trained: the CPU and its vector flags, torch's version and
    CPU capability, the compiler (contracts/float_setup.py); "" in records older than the field."""

    def to_json(self) -> dict[str, Any]:
        """The record as harness.json holds it: its paths as ``contracts.recorded_paths`` writes them."""
        d = asdict(self)
        for key in ("run_dir", "dataset", "stage2_from"):
            d[key] = recorded_path(d[key])
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "RunResult":
        return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})
