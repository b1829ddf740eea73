"""Stage 3: surface and smoke, jointly.

Each iteration renders one RGB training frame (surface ∪ smoke, RGB opacities, smoke alpha
from the same pass) and, when thermal is used, one thermal frame (surface ∪ smoke, thermal
opacities); adds the switchable priors; densifies the smoke as Deformable 3DGS does. Surface
Gaussians are static (no deformation) and are not densified here: their geometry is Stage 2's.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from smokeseer.config import TrainConfig
from smokeseer.data import ModalityData
from smokeseer.deform import DeformNetwork
from smokeseer.depth_prior import DepthPriorMaps
from smokeseer.gaussians import DensifyStrategy, GaussianSet, make_optimizer
from smokeseer.losses import (depth_consistency, mask_alignment, monochromaticity, render_loss,
                              smoke_alpha_variance, smoke_color_variance)
from smokeseer.model import SceneModel, add_rgb_sh, make_smoke, place_static, render
from smokeseer.stage2 import Stage2Result, make_background, views_of
from smokeseer.trainutil import (NaNDetected, RunContext, check_finite, exp_lr, grads_of,
                                 load_checkpoint, save_checkpoint)


@dataclass
class Stage3Switches:
    """Which inputs and loss terms this mode uses (a zero weight also switches a term off)."""

    use_thermal: bool
    use_smoke: bool
    use_deform: bool
    use_masks: bool


def loss_weights(cfg: TrainConfig) -> dict[str, float]:
    """The mode's loss weights: each ablation zeroes exactly one prior."""
    w = cfg.loss
    weights = {"render": w.render, "smoke_alpha": w.smoke_alpha, "smoke_color": w.smoke_color,
               "mono": w.mono, "depth": w.depth, "mask": w.mask,
               "thermal_smoke_opacity": w.thermal_smoke_opacity}
    off = {"no-smoke-alpha": "smoke_alpha", "no-smoke-color": "smoke_color", "no-mono": "mono",
           "no-depth": "depth", "no-mask": "mask"}.get(cfg.mode)
    if off:
        weights[off] = 0.0
    if cfg.depth_prior == "none":
        weights["depth"] = 0.0
    return weights


def build_scene_model(ctx: RunContext, s2: Stage2Result, switches: Stage3Switches,
                      smoke_points: np.ndarray | None, smoke_static: bool) -> SceneModel:
    """Surface from Stage 2 gains an RGB SH colour beside its thermal one (RGB-only runs already
    have it); smoke starts random in the scene bounds. Stage 2's environment carries over for
    its modality; the other modality's starts grey."""
    cfg = ctx.cfg
    tensors = s2.gaussians.state_dict()
    if "sh_dc" not in tensors:
        add_rgb_sh(tensors, cfg.sh_degree)
    tensors = {k: v.to(ctx.device) for k, v in tensors.items()}
    surf = GaussianSet(tensors)
    smoke = None
    deform = None
    if switches.use_smoke and smoke_points is not None:
        smoke = make_smoke(smoke_points, cfg.stage3.smoke_init_opacity, cfg.stage3.smoke_init_scale,
                           cfg.stage2.init_scale_max * ctx.extent, np.random.default_rng(cfg.seed + 1))
        for p in smoke.params.values():
            p.data = p.data.to(ctx.device)
        if switches.use_deform:
            deform = DeformNetwork(cfg.deform, ctx.extent).to(ctx.device)
    thermal_geometry = s2.color == "thermal"
    bg_rgb = make_background(cfg, 3, ctx.device) if thermal_geometry else s2.background
    bg_thermal = s2.background if thermal_geometry else None
    return SceneModel(surf, smoke, deform, smoke_static or not switches.use_deform, ctx.center, cfg.sh_degree,
                      background_rgb=bg_rgb, background_thermal=bg_thermal)


def _backgrounds(model: SceneModel) -> dict[str, torch.nn.Module]:
    return {name: bg for name, bg in (("background_rgb", model.background_rgb),
                                      ("background_thermal", model.background_thermal)) if bg is not None}


def _surface_lrs(cfg: TrainConfig, g: GaussianSet, extent: float) -> dict[str, float]:
    lr = cfg.lr
    geo = cfg.stage3.train_surface_geometry
    table = {"means": lr.means_init * extent if geo else 0.0, "quats": lr.quats if geo else 0.0,
             "log_scales": lr.scales if geo else 0.0, "opacity": lr.opacity if geo else 0.0,
             "thermal": lr.thermal, "sh_dc": lr.sh_dc, "sh_rest": lr.sh_rest}
    return {k: table[k] for k in g.params}


def _smoke_lrs(cfg: TrainConfig, extent: float) -> dict[str, float]:
    lr = cfg.lr
    return {"means": lr.means_init * extent, "quats": lr.quats, "log_scales": lr.scales,
            "opacity_rgb": lr.opacity, "opacity_thermal": lr.opacity, "color": lr.sh_dc * 4,
            "thermal": lr.thermal, "t_lo": lr.temporal, "t_hi": lr.temporal, "t_log_sigma": lr.temporal}


def train_stage3(ctx: RunContext, model: SceneModel, rgb: ModalityData, thermal: ModalityData | None,
                 switches: Stage3Switches, prior: DepthPriorMaps | None,
                 test_psnr: Callable[[SceneModel, int], float | None] | None = None) -> SceneModel:
    """Joint optimisation; resumes from checkpoints/stage3.pt."""
    cfg, dev = ctx.cfg, ctx.device
    total = cfg.stage3.iterations
    weights = loss_weights(cfg)
    start = 0
    ckpt = load_checkpoint(ctx.checkpoint_path(3), ctx.config_sha)
    if ckpt is not None:
        model.surface = GaussianSet({k: v.to(dev) for k, v in ckpt["surface"].items()})
        if ckpt.get("smoke") is not None:
            model.smoke = GaussianSet({k: v.to(dev) for k, v in ckpt["smoke"].items()})
        if model.deform is not None and ckpt.get("deform") is not None:
            model.deform.load_state_dict(ckpt["deform"])
        for name, bg in _backgrounds(model).items():
            if ckpt.get(name) is not None:
                bg.load_state_dict(ckpt[name])
        start = int(ckpt["iteration"])
    s_opt = make_optimizer(model.surface, _surface_lrs(cfg, model.surface, ctx.extent))
    k_opt = make_optimizer(model.smoke, _smoke_lrs(cfg, ctx.extent)) if model.smoke is not None else None
    d_opt = torch.optim.Adam(model.deform.parameters(), lr=cfg.deform.lr_init) if model.deform is not None else None
    bg_params = [p for bg in _backgrounds(model).values() for p in bg.parameters()]
    b_opt = torch.optim.Adam(bg_params, lr=cfg.lr.background) if bg_params else None
    if ckpt is not None:
        s_opt.load_state_dict(ckpt["surface_optimizer"])
        if k_opt is not None and ckpt.get("smoke_optimizer") is not None:
            k_opt.load_state_dict(ckpt["smoke_optimizer"])
        if d_opt is not None and ckpt.get("deform_optimizer") is not None:
            d_opt.load_state_dict(ckpt["deform_optimizer"])
        if b_opt is not None and ckpt.get("background_optimizer") is not None:
            b_opt.load_state_dict(ckpt["background_optimizer"])
        if ckpt.get("done"):
            ctx.log_line(f"stage 3: resumed finished stage from {ctx.checkpoint_path(3)}")
            return model
    strategy = DensifyStrategy(cfg.stage3.smoke_densify, ("opacity_rgb", "opacity_thermal"), ctx.extent)

    rgb_idx = rgb.indices("train")
    rgb_views = views_of(rgb, rgb_idx, dev)
    rgb_imgs = torch.as_tensor(rgb.images[rgb_idx], device=dev)
    masks = (torch.as_tensor(rgb.masks[rgb_idx], device=dev)
             if switches.use_masks and rgb.masks is not None and model.smoke is not None else None)
    th_views, th_imgs = [], None
    if switches.use_thermal and thermal is not None:
        th_idx = thermal.indices("train")
        th_views = views_of(thermal, th_idx, dev)
        th_imgs = torch.as_tensor(thermal.images[th_idx], device=dev)

    def payload(it: int, done: bool) -> dict:
        return {"stage": 3, "iteration": it, "done": done, "config_sha256": ctx.config_sha,
                "surface": model.surface.state_dict(), "surface_optimizer": s_opt.state_dict(),
                "smoke": model.smoke.state_dict() if model.smoke is not None else None,
                "smoke_optimizer": k_opt.state_dict() if k_opt is not None else None,
                "deform": model.deform.state_dict() if model.deform is not None else None,
                "deform_optimizer": d_opt.state_dict() if d_opt is not None else None,
                "background_optimizer": b_opt.state_dict() if b_opt is not None else None,
                **{name: bg.state_dict() for name, bg in _backgrounds(model).items()}}

    bar = tqdm(range(start + 1, total + 1), desc="stage 3", disable=not cfg.progress, leave=False)
    for it in bar:
        for opt in (s_opt, k_opt):
            if opt is None:
                continue
            for group in opt.param_groups:
                if group["name"] == "means" and group["lr"] > 0:
                    group["lr"] = exp_lr(it, total, cfg.lr.means_init * ctx.extent, cfg.lr.means_final * ctx.extent)
        deform_on = it > cfg.deform.warmup_iterations
        degree = min(cfg.sh_degree, (it - 1) // max(cfg.sh_increase_every, 1))
        k = int(torch.randint(len(rgb_views), (1,), generator=ctx.generator))
        view = rgb_views[k]
        out = model.render_rgb(view, degree=degree, deform_active=deform_on)
        terms: dict[str, torch.Tensor] = {}
        terms["render_rgb"] = render_loss(out.colors[0], rgb_imgs[k], cfg.loss.dssim)
        if th_imgs is not None:
            j = int(torch.randint(len(th_views), (1,), generator=ctx.generator))
            tout = model.render_thermal(th_views[j], deform_active=deform_on)
            terms["render_thermal"] = render_loss(tout.colors[0], th_imgs[j], cfg.loss.dssim)
        if model.smoke is not None:
            o_rgb = torch.sigmoid(model.smoke["opacity_rgb"])
            col = torch.sigmoid(model.smoke["color"])
            if weights["smoke_alpha"] > 0:
                terms["smoke_alpha"] = smoke_alpha_variance(o_rgb)
            if weights["smoke_color"] > 0:
                terms["smoke_color"] = smoke_color_variance(col)
            if weights["mono"] > 0:
                terms["mono"] = monochromaticity(col)
            if masks is not None and weights["mask"] > 0:
                terms["mask"] = mask_alignment(out.subset_alphas[0, ..., 0], masks[k])
            if th_imgs is not None and weights["thermal_smoke_opacity"] > 0:
                terms["thermal_smoke_opacity"] = torch.sigmoid(model.smoke["opacity_thermal"]).mean()
        if prior is not None and weights["depth"] > 0 and cfg.stage3.train_surface_geometry:
            sout = render(view, [(place_static(model.surface), torch.sigmoid(model.surface["opacity"]),
                                  torch.zeros(model.surface.n, 1, device=dev))], None, None,
                          normalize_depth=True)
            d = sout.depths[0, ..., 0]
            valid = prior.valid[k] & (sout.alphas[0, ..., 0] > 0.5)
            if prior.space == "disparity":
                d = 1.0 / d.clamp_min(1e-3)
            terms["depth"] = depth_consistency(d, prior.maps[k], valid)
        loss = sum(weights["render"] * v if n.startswith("render") else weights[n] * v for n, v in terms.items())
        try:
            check_finite(3, it, [(f"loss.{n}", v) for n, v in terms.items()])
            loss.backward()
            named = grads_of("surface", model.surface.params)
            if model.smoke is not None:
                named += grads_of("smoke", model.smoke.params)
            if model.deform is not None:
                named += [(f"deform.{n}.grad", p.grad) for n, p in model.deform.named_parameters()]
            named += [(f"{name}.coeffs.grad", bg.coeffs.grad) for name, bg in _backgrounds(model).items()]
            check_finite(3, it, named)
        except NaNDetected:
            save_checkpoint(ctx.out / "checkpoints" / "stage3_nan.pt", payload(it - 1, False))
            raise
        if model.smoke is not None and out.means2d.grad is not None:
            ns = model.surface.n
            strategy.accumulate(out.means2d.grad[0, ns:], out.radii[0, ns:], view.width, view.height)
        s_opt.step()
        s_opt.zero_grad(set_to_none=True)
        if k_opt is not None:
            k_opt.step()
            k_opt.zero_grad(set_to_none=True)
        if d_opt is not None:
            for group in d_opt.param_groups:
                group["lr"] = exp_lr(it, total, cfg.deform.lr_init, cfg.deform.lr_final)
            if deform_on:
                d_opt.step()
            d_opt.zero_grad(set_to_none=True)
        if b_opt is not None:
            b_opt.step()
            b_opt.zero_grad(set_to_none=True)
        try:
            named = [(f"surface.{k}", p) for k, p in model.surface.params.items()]
            if model.smoke is not None:
                named += [(f"smoke.{k}", p) for k, p in model.smoke.params.items()]
            check_finite(3, it, named)
        except NaNDetected:
            save_checkpoint(ctx.out / "checkpoints" / "stage3_nan.pt", payload(it, False))
            raise
        if model.smoke is not None and k_opt is not None:
            strategy.step(it, model.smoke, k_opt, ctx.generator)
        if it % cfg.log_every == 0 or it == total:
            tp = test_psnr(model, it) if test_psnr is not None and (it % cfg.stage3.test_every == 0 or it == total) else None
            row = {"stage": 3, "iteration": it, "n_gaussians": model.surface.n,
                   "n_smoke": model.smoke.n if model.smoke is not None else 0, "loss": float(loss.detach()),
                   "test_psnr": tp}
            row.update({n: float(v.detach()) for n, v in terms.items()})
            ctx.log.write(row)
            bar.set_postfix(loss=f"{float(loss.detach()):.4f}")
        if cfg.checkpoint_every and it % cfg.checkpoint_every == 0 and it < total:
            save_checkpoint(ctx.checkpoint_path(3), payload(it, False))
    save_checkpoint(ctx.checkpoint_path(3), payload(total, True))
    return model
