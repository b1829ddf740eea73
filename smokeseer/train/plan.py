"""The Stage 3 plan: what a run's Stage 3 trains with, decided in one place.

``plan_stage3`` takes the config, the loaded scene and where Stage 1's masks came from, and
decides the inputs (thermal, smoke Gaussians, deformation, masks), the smoke colour (learned,
or anchored to the haze-line estimate by its trust), where the mask floor acts, the depth prior
and its camera, and the loss weights that follow from all of them. The haze-line estimate needs
Stage 2's geometry, so ``Stage3Plan.settle_colour`` applies it then, by the same rule: a colour
held fixed (trust 1) leaves the smoke_color and mono priors nothing to act on, so they leave the
loss; under trust below 1 they act on the blended colours.

Stage 3 takes its weights from the plan; every term the mode asks for that the plan drops is
named with the reason (``dropped``), and the notes say it in the log and metrics.json.
``Stage3Plan.record`` is metrics.json ``stages.stage3_plan`` (docs/results-format.md), which the
harness reads (eval/twins.py). This module is public trainer API and imports no torch, so the
harness can ask ``depth_term_on`` without loading the trainer.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from contracts.results_format import STAGE3_PLAN_KEYS, RunWarning
from scenes.scene import SceneData
from smokeseer.config import TrainConfig
from smokeseer.stage1.haze_lines import SmokeColourEstimate
from smokeseer.stage1.input_checks import thermal_flat

TERMS = ("render", "smoke_alpha", "smoke_color", "mono", "depth", "mask", "thermal_smoke_opacity")
"""Stage 3's loss terms (``render`` weighs the RGB and the thermal render losses)."""
ABLATED_TERM = {"no-smoke-alpha": "smoke_alpha", "no-smoke-color": "smoke_color", "no-mono": "mono",
                "no-depth": "depth", "no-mask": "mask"}
"""The one prior each ablation mode zeroes."""
COLOUR_TERMS = ("smoke_color", "mono")
"""The priors on the smoke Gaussians' colours: nothing to act on when the colour is held fixed."""
SMOKE_TERMS = ("smoke_alpha", "smoke_color", "mono", "mask", "thermal_smoke_opacity")
"""Terms on the smoke Gaussians: none without them."""
COLOUR_FIXED = "the smoke colour is held fixed at the haze-line estimate"


def depth_term_on(cfg: TrainConfig) -> bool:
    """Whether the run has a depth term at all: a weight, a prior, a mode that keeps it, and a surface
    whose geometry trains (a frozen surface depth would give the term no gradient)."""
    return (cfg.loss.depth > 0 and cfg.depth_prior != "none" and cfg.mode not in ("no-depth", "deformable-3dgs")
            and cfg.stage3.train_surface_geometry)


def mode_weights(cfg: TrainConfig) -> dict[str, float]:
    """The config's loss weights with the mode's ablated prior at 0: what the mode asks for."""
    w = cfg.loss
    weights = {"render": w.render, "smoke_alpha": w.smoke_alpha, "smoke_color": w.smoke_color,
               "mono": w.mono, "depth": w.depth, "mask": w.mask,
               "thermal_smoke_opacity": w.thermal_smoke_opacity}
    off = ABLATED_TERM.get(cfg.mode)
    if off:
        weights[off] = 0.0
    return weights


def depth_camera(cfg: TrainConfig, use_thermal: bool) -> str:
    """The camera the depth term compares at: ``cfg.depth_camera``, except that a run without
    thermal input (rgb-only, a capture without thermal, or flat thermal frames) has only the RGB camera."""
    if cfg.depth_camera == "thermal" and not use_thermal:
        return "rgb"
    return cfg.depth_camera


def thermal_input(cfg: TrainConfig, scene: SceneData) -> tuple[str | None, RunWarning | None]:
    """Why the run trains without thermal (None: it trains with it), and the ``thermal-flat`` warning
    when the reason is frames without contrast: a method that would use them then trains as RGB-only
    does, since they teach Stage 2 no geometry."""
    if cfg.mode in ("rgb-only", "deformable-3dgs"):
        return f"{cfg.mode} reads no thermal", None
    if scene.thermal is None:
        return "the dataset has no thermal frames", None
    flat = thermal_flat(scene)
    return (flat.message, flat) if flat is not None else (None, None)


@dataclass
class Stage3Plan:
    """Which inputs, smoke colour, mask floor, depth prior and loss weights Stage 3 uses, and a line
    for every term or input the data made us drop (logged, and kept in metrics.json)."""

    use_thermal: bool
    use_smoke: bool
    use_deform: bool
    """Whether a deformation network trains: the smoke's (moving smoke only), or the
    deformable-3dgs baseline's single set. A run without smoke Gaussians has none."""
    use_masks: bool
    smoke_colour: str
    """"none" (no smoke Gaussians), "learned", or "haze-lines": anchored to ``colour``, the estimate
    made once Stage 2 has given the geometry, by ``trust`` (``settle_colour``)."""
    mask_floor: str
    """Where the mask term's floor acts: "all", "never-clear", "estimated-meeting", or
    "estimated-bound" (a target per pixel in place of the floor) (``loss.mask_floor_where``)."""
    depth_prior: str | None
    """The prior the depth term compares with; None: the run has no depth term."""
    depth_camera: str | None
    weights: dict[str, float]
    """Every term's weight in the loss; 0: the term is not in it."""
    dropped: dict[str, str] = field(default_factory=dict)
    """Terms the mode asks for that the plan leaves out, with the reason."""
    notes: list[str] = field(default_factory=list)
    colour: np.ndarray | None = None
    """The haze-line RGB smoke colour, or None when the smoke Gaussians learn theirs freely."""
    trust: float = 0.0
    """Each smoke Gaussian shows trust × ``colour`` + (1 − trust) × its own learned colour."""
    floor_pixels: np.ndarray | None = None
    """(training RGB frames, H, W) bool: where the mask floor acts (never-clear or estimated-meeting, set
    once Stage 2 has given the geometry and the smoke colour is settled); None: everywhere."""
    alpha_targets: np.ndarray | None = None
    """(training RGB frames, H, W) in [0, 1]: with estimated-bound, the smoke alpha the mask term
    pushes each masked pixel up to (``mask_floor.estimated_alpha_bound``); None otherwise."""
    thermal_dropped: str | None = None
    """Why the run trains without thermal (metrics.json ``stages.thermal_dropped``); None when it uses it."""
    thermal_warning: RunWarning | None = None
    """The ``thermal-flat`` warning when flat thermal frames were the reason."""

    def drop(self, term: str, why: str) -> None:
        """Take ``term`` out of the loss; the record says why when the mode asked for it."""
        if self.weights[term] > 0:
            self.dropped[term] = why
        self.weights[term] = 0.0

    def settle_colour(self, estimate: SmokeColourEstimate) -> str | None:
        """Apply the haze-line estimate by its trust: at 0 (or without an estimate) the colours are
        learned as in the paper; between 0 and 1 each smoke Gaussian blends the estimate with its
        own colour; at 1 the colour is held, so the colour priors leave the loss. Returns the note."""
        if estimate.colour is None or estimate.trust == 0.0:
            self.smoke_colour = "learned"
            return ("smoke colour: the haze-line estimate has no trust, so the smoke Gaussians learn "
                    f"their colours as in the paper ({estimate.reason})")
        self.colour, self.trust = estimate.colour, estimate.trust
        if estimate.trust < 1.0:
            return (f"smoke colour: each smoke Gaussian shows {estimate.trust:.3f} × the haze-line estimate "
                    f"{np.round(estimate.colour, 3).tolist()} + {1 - estimate.trust:.3f} × its own learned colour "
                    f"({estimate.reason})")
        dropped = [name for name in COLOUR_TERMS if self.weights[name] > 0]
        for name in COLOUR_TERMS:
            self.drop(name, COLOUR_FIXED)
        if not dropped:
            return None
        return (f"{' and '.join(dropped)} term{'s' if len(dropped) > 1 else ''} dropped: the smoke colour is held "
                "fixed at the haze-line estimate, so there is no colour spread for them to act on")

    def record(self) -> dict[str, Any]:
        """metrics.json ``stages.stage3_plan``."""
        values = (self.smoke_colour, self.mask_floor, self.depth_prior, self.depth_camera, dict(self.weights),
                  dict(self.dropped))
        return dict(zip(STAGE3_PLAN_KEYS, values))


def plan_stage3(cfg: TrainConfig, scene: SceneData) -> Stage3Plan:
    """The plan from the config and the data after Stage 1. No smoke in the masks → no smoke Gaussians and no deformation network; static smoke →
    no deformation network; no thermal, or thermal frames without contrast → rgb-only. Raises ValueError when the config asks for
    depth maps the data does not have."""
    masks = scene.rgb.masks
    deformable = cfg.mode == "deformable-3dgs"
    smoke_seen = scene.smoke_present and (masks is None or bool((masks[scene.rgb.indices("train")] > 0).any()))
    use_smoke = smoke_seen and not deformable
    thermal_dropped, thermal_warning = thermal_input(cfg, scene)
    use_thermal = thermal_dropped is None
    depth_on = depth_term_on(cfg)
    camera = depth_camera(cfg, use_thermal) if depth_on else None
    colour = "none" if not use_smoke else cfg.stage3.smoke_color
    plan = Stage3Plan(use_thermal=use_thermal, use_smoke=use_smoke,
                      use_deform=deformable or (use_smoke and not scene.smoke_static), use_masks=masks is not None,
                      smoke_colour=colour, mask_floor="all",
                      depth_prior=cfg.depth_prior if depth_on else None, depth_camera=camera,
                      weights=mode_weights(cfg), thermal_dropped=thermal_dropped, thermal_warning=thermal_warning)
    if not depth_on:
        plan.drop("depth", "the deformable-3dgs baseline has no Stage 3" if deformable
                  else "depth_prior is none" if cfg.depth_prior == "none"
                  else "stage3.train_surface_geometry is false, so the surface depth is frozen and the term has no gradient")
    if not use_smoke:
        for term in SMOKE_TERMS:
            plan.drop(term, "no smoke Gaussians")
    elif masks is None:
        plan.drop("mask", "the dataset has no smoke masks")
    if not use_thermal:
        plan.drop("thermal_smoke_opacity", "no thermal input")
    if not deformable:
        plan.notes += _dropped_term_notes(cfg, plan)
    _check_depth_files(cfg, scene, plan)
    plan.notes += _depth_file_notes(cfg, scene, plan)
    plan.mask_floor = _mask_floor(cfg, plan)
    if camera is not None and camera != cfg.depth_camera:
        plan.notes.append(f"depth term at the {camera} camera, not {cfg.depth_camera}: this run has no thermal input")
    return plan


def _dropped_term_notes(cfg: TrainConfig, plan: Stage3Plan) -> list[str]:
    """Why a prior the mode asks for is not in the loss: each becomes a log line and a note in
    metrics.json, never a silent difference between runs."""
    notes = []
    if "depth" in plan.dropped:
        notes.append(f"depth term dropped: {plan.dropped['depth']}")
    if not plan.use_masks and cfg.mode != "rgb-only":
        notes.append("mask term dropped: the dataset has no smoke masks"
                     + (", so this no-mask run trains exactly like full" if cfg.mode == "no-mask" else ""))
    return notes


def _check_depth_files(cfg: TrainConfig, scene: SceneData, plan: Stage3Plan) -> None:
    if plan.depth_prior != "files":
        return
    mod = scene.thermal if plan.depth_camera == "thermal" else scene.rgb
    if mod is None or mod.inverse_depth is None:
        raise ValueError(f"depth_prior: files needs depth maps for the {plan.depth_camera} frames, and {scene.path} "
                         "has none (the official COLMAP layout's images_depth/ with sparse/0/depth_params.json)")


def _depth_file_notes(cfg: TrainConfig, scene: SceneData, plan: Stage3Plan) -> list[str]:
    """The layout's depth maps (official ``images_depth``) that this run reads but does not use,
    and why: never a silent difference from the official code, which uses them."""
    used = plan.depth_camera if plan.depth_prior == "files" else None
    notes = []
    for mod in (scene.rgb, scene.thermal):
        if mod is None or mod.inverse_depth is None or mod.name == used:
            continue
        why = (f"depth_prior is {cfg.depth_prior} (--set depth_prior=files uses them)" if cfg.depth_prior != "files"
               else "this run has no depth term" if used is None
               else f"the depth term compares at the {used} camera (depth_camera)")
        notes.append(f"images_depth: the {mod.name} frames' depth maps are read but not used: {why}")
    return notes


def _mask_floor(cfg: TrainConfig, plan: Stage3Plan) -> str:
    """The pixels the mask floor acts on: "all", "never-clear", "estimated-meeting" or
    "estimated-bound"; "all" without masks or smoke, where there is nothing to gate."""
    where = cfg.loss.mask_floor_where
    if where == "all" or not (plan.use_smoke and plan.use_masks):
        return "all"
    return where
