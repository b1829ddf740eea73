"""Stage 3: surface and smoke, jointly.

Each iteration renders one RGB training frame (surface ∪ smoke, RGB opacities, smoke alpha
from the same pass) and, when thermal is used, one thermal frame (surface ∪ smoke, thermal
opacities); adds the switchable priors; densifies the smoke as Deformable 3DGS does. Surface
Gaussians are static (no deformation); with ``stage3.surface_densify`` on they are also cloned,
split and pruned from the RGB views' gradients (the paper's "refining geometry"), otherwise
their count is Stage 2's.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
import torch

from scenes.scene import ModalityData
from smokeseer.config import TrainConfig, at_iteration
from smokeseer.config.streams import numpy_stream
from smokeseer.model.deform import DeformNetwork, motion_tensors
from smokeseer.model.planes import PlaneField
from smokeseer.model.gaussians import DensifyStrategy, GaussianSet, make_optimizer
from smokeseer.model.optim import Adam
from smokeseer.model.scene import SceneModel, SmokeAnchor, add_rgb_sh, make_smoke
from smokeseer.raster.output import RasterOutput, box_filtered
from smokeseer.train.depth_prior import DepthPriorMaps
from smokeseer.train.loop import IterationOutput, StageProblem, StageSchedule, run_stage
from smokeseer.train.losses import (depth_consistency, mask_alignment, monochromaticity, render_loss,
                                    smoke_alpha_variance, smoke_color_variance)
from smokeseer.train.plan import Stage3Plan
from smokeseer.train.stage2 import Stage2Result, clear_pixel_weights, draw_index, make_background, views_of
from smokeseer.train.surface_union import smoky_share
from smokeseer.train.util import RunContext, grads_of, state_or_none, step_optimizers

HeldoutPsnr = Callable[[SceneModel, int], dict[str, float | None] | None]

SHARE_REFRESH = 100
"""Each surface Gaussian's view share (``ViewShare``) is recomputed at the start of every block of
this many iterations, and whenever densification has changed the surface's count (it acts at most
once a block): its position moves far less than a pixel between."""

class ViewShare:
    """Per surface Gaussian, the share of the RGB training views whose Stage-1 mask covers its centre
    (``smoky_share``; 1 where no view sees it), cached as ``SHARE_REFRESH`` says (once per
    iteration: the start's note and iteration 1 read the same positions)."""

    def __init__(self, masks: np.ndarray, viewmats: np.ndarray, Ks: np.ndarray) -> None:
        self.inputs = (masks, viewmats, Ks)
        self.value: torch.Tensor | None = None
        self.read_at: int | None = None

    def at(self, it: int, surface: GaussianSet) -> torch.Tensor:
        block_start = (it - 1) % SHARE_REFRESH == 0 and it != self.read_at
        if self.value is None or block_start or len(self.value) != surface.n:
            means = surface["means"].detach().cpu().numpy().astype(np.float64)
            share = smoky_share(means, *self.inputs)
            self.value = torch.as_tensor(share, dtype=torch.float32, device=surface["means"].device)
            self.read_at = it
        return self.value


def build_scene_model(ctx: RunContext, s2: Stage2Result, plan: Stage3Plan,
                      smoke_points: np.ndarray | None, smoke_static: bool,
                      rgb_s2: Stage2Result | None = None, surface: GaussianSet | None = None) -> SceneModel:
    """Surface from Stage 2 gains an RGB SH colour beside its thermal one (RGB-only runs already
    have it), unless ``surface`` gives it (both Stage 2s joined); smoke starts at ``smoke_points``
    with temporal opacities drawn from the stream ``init.smoke.temporal``. Each Stage 2's
    environment carries over for its modality (``rgb_s2`` is the RGB Stage 2 of a two-surface run);
    a modality without one starts grey."""
    cfg = ctx.cfg
    if surface is None:
        tensors = {k: v.to(ctx.device) for k, v in s2.gaussians.state_dict().items()}
        if "sh_dc" not in tensors:
            add_rgb_sh(tensors, cfg.sh_degree)
        surface = GaussianSet(tensors)
    smoke = None
    deform = None
    if plan.use_smoke and smoke_points is not None:
        smoke = make_smoke(smoke_points, cfg.stage3.smoke_init_opacity, cfg.stage3.smoke_init_scale,
                           cfg.stage2.init_scale_max * ctx.extent, numpy_stream(cfg.seed, "init.smoke.temporal"),
                           ctx.device)
        if plan.use_deform and cfg.deform.kind == "mlp":
            with ctx.seeded_torch("stage3.deform"):
                deform = DeformNetwork(cfg.deform, ctx.extent, ctx.device)
        elif plan.use_deform and cfg.deform.kind == "planes":
            with ctx.seeded_torch("stage3.deform"):
                deform = PlaneField(cfg.deform, *planes_domain(smoke_points, cfg.deform.planes_margin, ctx.extent),
                                    ctx.extent, ctx.device)
        elif plan.use_deform:
            smoke = GaussianSet({**smoke.state_dict(), **motion_tensors(smoke.n, cfg.deform, ctx.device)})
    thermal_geometry = s2.color == "thermal"
    bg_rgb = (rgb_s2.background if rgb_s2 is not None else make_background(cfg, 3, ctx.device)) \
        if thermal_geometry else s2.background
    bg_thermal = s2.background if thermal_geometry else None
    anchor = (SmokeAnchor(torch.as_tensor(plan.colour, dtype=torch.float32, device=ctx.device), plan.trust)
              if smoke is not None and plan.colour is not None else None)
    return SceneModel(surface, smoke, deform, smoke_static or not plan.use_deform, ctx.center, cfg.sh_degree,
                      background_rgb=bg_rgb, background_thermal=bg_thermal, smoke_anchor=anchor)


def planes_domain(points: np.ndarray, margin: float, extent: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The plane field's box: the smoke's starting points' bounding box grown by ``margin`` × its
    size on every side (each side at least a thousandth of the scene extent, so a flat start still
    spans a box)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    grow = np.maximum(margin * (hi - lo), 1e-3 * extent)
    return torch.as_tensor(lo - grow), torch.as_tensor(hi + grow)


def _backgrounds(model: SceneModel) -> dict[str, torch.nn.Module]:
    return {name: bg for name, bg in (("background_rgb", model.background_rgb),
                                      ("background_thermal", model.background_thermal)) if bg is not None}


def _surface_lrs(cfg: TrainConfig, g: GaussianSet, extent: float) -> dict[str, float]:
    """The surface's rates: Stage 2's, its position's decaying again from ``lr.means_init``."""
    lr = cfg.lr
    geo = 1.0 if cfg.stage3.train_surface_geometry else 0.0
    table = {"means": lr.means_init * extent * geo, "quats": lr.quats * geo,
             "log_scales": lr.scales * geo, "opacity": lr.opacity * geo,
             "thermal": lr.thermal, "sh_dc": lr.sh_dc, "sh_rest": lr.sh_rest}
    return {k: table[k] for k in g.params}


def _smoke_lrs(cfg: TrainConfig, extent: float) -> dict[str, float]:
    lr = cfg.lr
    table = {"means": lr.means_init * extent, "quats": lr.quats, "log_scales": lr.scales,
             "opacity_rgb": lr.opacity, "opacity_thermal": lr.opacity, "color": lr.sh_dc * 4,
             "thermal": lr.thermal, "t_lo": lr.temporal, "t_hi": lr.temporal, "t_log_sigma": lr.temporal}
    return {**table, **{f"motion_{k}": table[k] * cfg.deform.fourier_lr_scale for k in ("means", "quats", "log_scales")}}


class Stage3Problem(StageProblem):
    """Joint optimisation of surface and smoke with the plan's loss terms."""

    stage = 3
    name = "stage 3"
    checkpoint = "stage3"

    def __init__(self, ctx: RunContext, model: SceneModel, rgb: ModalityData, thermal: ModalityData | None,
                 plan: Stage3Plan, prior: DepthPriorMaps | None,
                 heldout_psnr: HeldoutPsnr | None) -> None:
        cfg, dev = ctx.cfg, ctx.device
        self.ctx, self.cfg, self.model, self.prior, self.heldout_fn = ctx, cfg, model, prior, heldout_psnr
        self.weights = {**plan.weights, "planes_tv": cfg.deform.planes_tv,
                        "planes_time": cfg.deform.planes_time_smoothness}
        self._make_optimizers()
        self.strategy = DensifyStrategy(cfg.stage3.smoke_densify, cfg.stage3.iterations, ("opacity_rgb", "opacity_thermal"),
                                        ctx.extent)
        self.deform_warmup = at_iteration(cfg.stage3.deform_warmup, cfg.stage3.iterations)
        refine = cfg.stage3.train_surface_geometry and cfg.stage3.surface_densify.every > 0
        self.surface_strategy = (DensifyStrategy(cfg.stage3.surface_densify, cfg.stage3.iterations, ("opacity",), ctx.extent)
                                 if refine else None)
        self.streams = {name: ctx.stream(name) for name in ("stage3.views.rgb", "stage3.views.thermal",
                                                             "stage3.splits.smoke", "stage3.splits.surface")}
        rgb_idx = rgb.indices("train")
        self.rgb_views = views_of(rgb, rgb_idx, dev)
        self.rgb_imgs = torch.as_tensor(rgb.images[rgb_idx], device=dev)
        self.masks = (torch.as_tensor(rgb.masks[rgb_idx], device=dev)
                      if plan.use_masks and rgb.masks is not None and model.smoke is not None else None)
        self.mask_floor = (torch.as_tensor(plan.floor_pixels, device=dev)
                           if self.masks is not None and plan.floor_pixels is not None else None)
        self.alpha_targets = (torch.as_tensor(plan.alpha_targets, dtype=self.masks.dtype, device=dev)
                              if self.masks is not None and plan.alpha_targets is not None else None)
        self.background_grad = (clear_pixel_weights(cfg, rgb, rgb_idx, dev)
                                if model.background_rgb is not None else None)
        self.th_views: list = []
        self.th_imgs = None
        if plan.use_thermal and thermal is not None:
            th_idx = thermal.indices("train")
            self.th_views = [v.supersampled(cfg.stage3.thermal_supersample) for v in views_of(thermal, th_idx, dev)]
            self.th_imgs = torch.as_tensor(thermal.images[th_idx], device=dev)
            if cfg.stage3.thermal_supersample > 1:
                s = cfg.stage3.thermal_supersample
                note = (f"the thermal term averages {s}x{s} sub-pixels to each thermal pixel "
                        f"({self.th_views[0].width}x{self.th_views[0].height} rendered for "
                        f"{thermal.images.shape[2]}x{thermal.images.shape[1]}; stage3.thermal_supersample={s})")
                plan.notes.append(note)
                ctx.log_line(f"stage 3: {note}")
        self.gate_thermal = self.th_imgs is not None and cfg.stage3.thermal_surface_grad == "smoky-views"
        if self.gate_thermal and model.smoke is not None and rgb.masks is None:
            raise ValueError("stage3.thermal_surface_grad: smoky-views reads Stage 1's smoke masks, "
                             "and this run's RGB frames have none")
        self.thermal_share: ViewShare | None = None
        if self.gate_thermal:
            masks = (rgb.masks[rgb_idx] if model.smoke is not None
                     else np.zeros((len(rgb_idx), *rgb.images.shape[1:3]), dtype=np.float32))
            self.thermal_share = ViewShare(masks, *rgb.cameras("train"))
            share = self.thermal_share.at(1, model.surface)
            note = (f"the thermal term moves each surface Gaussian by the share of the RGB training views whose "
                    f"smoke mask covers it: mean {float(share.mean()):.3f} at the start, "
                    f"{100 * float((share == 0).float().mean()):.0f} % not at all"
                    + ("" if model.smoke is not None else " (no smoke: only what no RGB view sees)")
                    + " (stage3.thermal_surface_grad=smoky-views)")
            plan.notes.append(note)
            ctx.log_line(f"stage 3: {note}")
        self.depth_on = prior is not None and self.weights["depth"] > 0
        self.depth_on_thermal = self.depth_on and prior.camera == "thermal"
        if self.depth_on_thermal and self.th_imgs is None:
            raise ValueError("stage 3: the depth prior is on the thermal camera but this run has no thermal images")

    def _make_optimizers(self) -> None:
        cfg, model = self.cfg, self.model
        self.surface_optimizer = make_optimizer(model.surface, _surface_lrs(cfg, model.surface, self.ctx.extent))
        self.smoke_optimizer = (make_optimizer(model.smoke, _smoke_lrs(cfg, self.ctx.extent))
                                if model.smoke is not None else None)
        groups = (model.deform.parameter_groups(cfg.deform.lr_init) if isinstance(model.deform, PlaneField)
                  else model.deform.parameters()) if model.deform is not None else None
        self.deform_optimizer = Adam(groups, lr=cfg.deform.lr_init) if groups is not None else None
        bg_params = [p for bg in _backgrounds(model).values() for p in bg.parameters()]
        self.background_optimizer = Adam(bg_params, lr=cfg.lr.background) if bg_params else None

    def forward(self, it: int) -> IterationOutput:
        cfg, model, weights = self.cfg, self.model, self.weights
        deform_on = it > self.deform_warmup
        degree = min(cfg.sh_degree, (it - 1) // max(cfg.sh_increase_every, 1))
        k = draw_index(self.streams["stage3.views.rgb"], len(self.rgb_views))
        view = self.rgb_views[k]
        motion = model.smoke_motion(deform_on, cfg.deform.shared_position,
                                    cfg.deform.view_cull_margin * self.ctx.extent if cfg.deform.view_cull else None)
        out = model.render_rgb(view, degree=degree, deform_active=deform_on,
                               surface_depth=self.depth_on and not self.depth_on_thermal, depth=False, motion=motion,
                               background_grad=None if self.background_grad is None else self.background_grad[k])
        terms: dict[str, torch.Tensor] = {"render_rgb": render_loss(out.colors[0], self.rgb_imgs[k], cfg.loss.dssim)}
        depth_source = (out, k)
        if self.th_imgs is not None:
            j = draw_index(self.streams["stage3.views.thermal"], len(self.th_views))
            tout = box_filtered(model.render_thermal(self.th_views[j], deform_active=deform_on,
                                                     surface_depth=self.depth_on_thermal, depth=False, motion=motion,
                                                     surface_grad_share=None if self.thermal_share is None
                                                     else self.thermal_share.at(it, model.surface)),
                                cfg.stage3.thermal_supersample)
            terms["render_thermal"] = render_loss(tout.colors[0], self.th_imgs[j], cfg.loss.dssim)
            if self.depth_on_thermal:
                depth_source = (tout, j)
        if model.smoke is not None:
            o_rgb = torch.sigmoid(model.smoke["opacity_rgb"])
            col = model.smoke_colours()
            if weights["smoke_alpha"] > 0:
                terms["smoke_alpha"] = smoke_alpha_variance(o_rgb)
            if weights["smoke_color"] > 0:
                terms["smoke_color"] = smoke_color_variance(col)
            if weights["mono"] > 0:
                terms["mono"] = monochromaticity(col)
            if self.masks is not None and weights["mask"] > 0:
                terms["mask"] = mask_alignment(out.subset_alphas[0, ..., 0], self.masks[k],
                                               cfg.loss.mask_alpha_floor,
                                               None if self.mask_floor is None else self.mask_floor[k],
                                               None if self.alpha_targets is None else self.alpha_targets[k])
            if self.th_imgs is not None and weights["thermal_smoke_opacity"] > 0:
                terms["thermal_smoke_opacity"] = torch.sigmoid(model.smoke["opacity_thermal"]).mean()
        if self.depth_on:
            terms["depth"] = self._depth_term(*depth_source)
        if motion is not None and isinstance(model.deform, PlaneField):
            terms["planes_tv"], terms["planes_time"] = model.deform.smoothness()
        share = {"render_rgb": 1.0, "render_thermal": cfg.loss.thermal}
        loss = sum(weights["render"] * share[n] * v if n in share else weights[n] * v for n, v in terms.items())
        return IterationOutput(loss, terms, {"raster": out, "view": view, "index": k, "deform_on": deform_on})

    def _depth_term(self, raster: RasterOutput, k: int) -> torch.Tensor:
        """The surface's own depth (from the same pass, see ``model.render``) against
        the prior of view ``k`` of the prior's camera."""
        d = raster.rest_depths[0, ..., 0]
        valid = self.prior.valid[k] & (raster.rest_alphas[0, ..., 0] > 0.5)
        if self.prior.space == "disparity":
            d = 1.0 / d.clamp_min(1e-3)
        return depth_consistency(d, self.prior.maps[k], valid)

    def named_gradients(self) -> list[tuple[str, torch.Tensor | None]]:
        model = self.model
        named = grads_of("surface", model.surface.params)
        if model.smoke is not None:
            named += grads_of("smoke", model.smoke.params)
        if model.deform is not None:
            named += [(f"deform.{n}.grad", p.grad) for n, p in model.deform.named_parameters()]
        named += [(f"{name}.coeffs.grad", bg.coeffs.grad) for name, bg in _backgrounds(model).items()]
        return named

    def named_parameters(self) -> list[tuple[str, torch.Tensor]]:
        named = [(f"surface.{k}", p) for k, p in self.model.surface.params.items()]
        if self.model.smoke is not None:
            named += [(f"smoke.{k}", p) for k, p in self.model.smoke.params.items()]
        return named

    def optimizer_step(self, it: int) -> None:
        """The position rates of both sets decay over Stage 3 from ``lr.means_init``."""
        step_optimizers(it, self.cfg.stage3.iterations, self.cfg, self.ctx.extent,
                        [self.surface_optimizer, self.smoke_optimizer], [self.background_optimizer],
                        self.deform_optimizer, self.deform_warmup)

    def after_step(self, it: int, out: IterationOutput) -> None:
        """Density control from the RGB render's screen-space gradients: the smoke's, and the
        surface's when it is refined. Both accumulate before either set changes size."""
        model = self.model
        raster, view = out.extra["raster"], out.extra["view"]
        ns = model.surface.n
        grad = raster.means2d.grad
        smoke = model.smoke is not None and self.smoke_optimizer is not None
        if grad is not None:
            if self.surface_strategy is not None:
                clear = smoke_free_centres(raster.means2d[0, :ns], self._smoke_cover(raster, out.extra["index"]),
                                           self.cfg.stage3.surface_densify_max_smoke)
                radii = torch.where(clear, raster.radii[0, :ns], torch.zeros_like(raster.radii[0, :ns]))
                self.surface_strategy.accumulate(grad[0, :ns], radii, view.width, view.height)
            if smoke:
                self.strategy.accumulate(grad[0, ns:], raster.radii[0, ns:], view.width, view.height)
        if self.surface_strategy is not None:
            self.surface_strategy.step(it, model.surface, self.surface_optimizer, self.streams["stage3.splits.surface"])
        if smoke:
            self.strategy.step(it, model.smoke, self.smoke_optimizer, self.streams["stage3.splits.smoke"])

    def raised_loss(self, it: int) -> bool:
        return any(s is not None and s.resets_opacity(it) for s in (self.strategy, self.surface_strategy))

    def _smoke_cover(self, raster: RasterOutput, k: int) -> torch.Tensor | None:
        """Where this RGB view has smoke: the smoke alpha of the same render pass, and the Stage 1
        mask where the run uses one (either one calling a pixel smoky is enough)."""
        cover = _rendered_smoke_alpha(raster)
        if cover is None or self.masks is None:
            return cover
        return torch.maximum(cover, self.masks[k])

    def state(self) -> dict[str, Any]:
        model = self.model
        return {"surface": model.surface.state_dict(), "surface_optimizer": self.surface_optimizer.state_dict(),
                "smoke": state_or_none(model.smoke), "smoke_optimizer": state_or_none(self.smoke_optimizer),
                "deform": state_or_none(model.deform), "deform_optimizer": state_or_none(self.deform_optimizer),
                "background_optimizer": state_or_none(self.background_optimizer),
                "thermal_share": None if self.thermal_share is None else self.thermal_share.value,
                **{name: bg.state_dict() for name, bg in _backgrounds(model).items()}}

    def load_state(self, payload: dict[str, Any]) -> None:
        model, dev = self.model, self.ctx.device
        model.surface = GaussianSet({k: v.to(dev) for k, v in payload["surface"].items()})
        if payload.get("smoke") is not None:
            model.smoke = GaussianSet({k: v.to(dev) for k, v in payload["smoke"].items()})
        if model.deform is not None and payload.get("deform") is not None:
            model.deform.load_state_dict(payload["deform"])
        for name, bg in _backgrounds(model).items():
            if payload.get(name) is not None:
                bg.load_state_dict(payload[name])
        if self.thermal_share is not None:
            value = payload.get("thermal_share")
            self.thermal_share.value = None if value is None else value.to(dev)
        self._make_optimizers()
        self.surface_optimizer.load_state_dict(payload["surface_optimizer"])
        for opt, key in ((self.smoke_optimizer, "smoke_optimizer"), (self.deform_optimizer, "deform_optimizer"),
                         (self.background_optimizer, "background_optimizer")):
            if opt is not None and payload.get(key) is not None:
                opt.load_state_dict(payload[key])

    def log_row(self, it: int, out: IterationOutput, heldout: dict[str, float | None] | None) -> dict[str, Any]:
        model = self.model
        row: dict[str, Any] = {"stage": 3, "iteration": it, "n_gaussians": model.surface.n,
                               "n_smoke": model.smoke.n if model.smoke is not None else 0,
                               "loss": float(out.loss.detach()), **(heldout or {})}
        row.update({n: float(v.detach()) for n, v in out.terms.items()})
        return row

    def heldout_psnr(self, it: int) -> dict[str, float | None] | None:
        return None if self.heldout_fn is None else self.heldout_fn(self.model, it)


def _rendered_smoke_alpha(raster: RasterOutput) -> torch.Tensor | None:
    """The smoke alpha the RGB pass accumulated (detached: it selects or weights pixels, it is
    not a loss); None when the run has no smoke Gaussians."""
    return None if raster.subset_alphas is None else raster.subset_alphas[0, ..., 0].detach()


def smoke_free_centres(means2d: torch.Tensor, smoke_cover: torch.Tensor | None, max_smoke: float) -> torch.Tensor:
    """True for each Gaussian whose projected centre lies on a pixel with smoke cover at most
    ``max_smoke``: its screen-space gradient there comes from surface, not from smoke. A centre
    outside the image does not count (how much smoke its footprint meets is not known); no smoke
    model (``None``) makes every Gaussian clear."""
    if smoke_cover is None:
        return torch.ones(means2d.shape[0], dtype=torch.bool, device=means2d.device)
    h, w = smoke_cover.shape
    px = means2d[:, 0].detach().floor()
    py = means2d[:, 1].detach().floor()
    inside = (px >= 0) & (px < w) & (py >= 0) & (py < h)  # False for NaN: gsplat leaves culled centres unwritten
    zero = torch.zeros_like(px)
    rows, cols = torch.where(inside, py, zero).long(), torch.where(inside, px, zero).long()
    return inside & (smoke_cover[rows, cols] <= max_smoke)


def train_stage3(ctx: RunContext, model: SceneModel, rgb: ModalityData, thermal: ModalityData | None,
                 plan: Stage3Plan, prior: DepthPriorMaps | None,
                 heldout_psnr: HeldoutPsnr | None = None) -> SceneModel:
    """Stage 3 through the shared loop; resumes from checkpoints/stage3.pt."""
    cfg = ctx.cfg
    problem = Stage3Problem(ctx, model, rgb, thermal, plan, prior, heldout_psnr)
    run_stage(ctx, problem, StageSchedule(cfg.stage3.iterations, cfg.log_every, cfg.stage3.test_every,
                                          cfg.checkpoint_every, ctx.config_sha))
    return problem.model
