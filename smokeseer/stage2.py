"""Stage 2: vanilla 3DGS on one modality (thermal for SmokeSeer: smoke barely touches LWIR, so
thermal images reveal the geometry). With a deformation network the same loop is the
Deformable-3DGS backbone used by the ``deformable-3dgs`` baseline."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from smokeseer.background import EnvironmentBackground
from smokeseer.config import DeformConfig, TrainConfig
from smokeseer.data import ModalityData
from smokeseer.deform import DeformNetwork
from smokeseer.gaussians import DensifyStrategy, GaussianSet, make_optimizer
from smokeseer.losses import render_loss
from smokeseer.model import View, add_rgb_sh, init_gaussians, make_view, place_deformed, render, sh_coeffs
from smokeseer.trainutil import (NaNDetected, RunContext, check_finite, exp_lr, grads_of, load_checkpoint,
                                 save_checkpoint)


@dataclass
class Stage2Result:
    """Trained Gaussians; ``color`` is "thermal" (a 1-channel logit) or "rgb" (SH); the learned
    environment of that modality (None with a black background)."""

    gaussians: GaussianSet
    deform: DeformNetwork | None
    color: str
    background: EnvironmentBackground | None


def views_of(mod: ModalityData, idx: list[int], device: torch.device) -> list[View]:
    return [make_view(mod.frames[i].viewmat, mod.frames[i].K, mod.frames[i].width, mod.frames[i].height,
                      mod.frames[i].time, device) for i in idx]


def colors_for(g: GaussianSet, color: str) -> tuple[torch.Tensor, bool]:
    """Rasterizer colours and whether they are SH."""
    if color == "thermal":
        return torch.sigmoid(g["thermal"]), False
    return sh_coeffs(g), True


def stage2_lrs(cfg: TrainConfig, g: GaussianSet, extent: float) -> dict[str, float]:
    lr = cfg.lr
    table = {"means": lr.means_init * extent, "quats": lr.quats, "log_scales": lr.scales,
             "opacity": lr.opacity, "thermal": lr.thermal, "sh_dc": lr.sh_dc, "sh_rest": lr.sh_rest}
    return {k: table[k] for k in g.params}


def make_background(cfg: TrainConfig, channels: int, device: torch.device) -> EnvironmentBackground | None:
    if cfg.background == "black":
        return None
    return EnvironmentBackground(channels, cfg.background_sh_degree).to(device)


def train_stage2(ctx: RunContext, mod: ModalityData, init_points: np.ndarray, deformable: bool,
                 test_psnr: Callable[[GaussianSet, DeformNetwork | None, EnvironmentBackground | None, int],
                                     float | None] | None = None
                 ) -> Stage2Result:
    """Fit Gaussians to ``mod``'s training frames with the 3DGS recipe (L1 + D-SSIM,
    densification, opacity reset, SH degree schedule); resumes from checkpoints/stage2.pt."""
    cfg, dev = ctx.cfg, ctx.device
    s2 = cfg.stage2
    color = "thermal" if mod.name == "thermal" else "rgb"
    tensors = init_gaussians(init_points, s2.init_opacity, s2.init_scale_max * ctx.extent)
    if color == "thermal":
        tensors["thermal"] = torch.zeros((len(init_points), 1))
    else:
        add_rgb_sh(tensors, cfg.sh_degree)
    g = GaussianSet(tensors)
    deform = DeformNetwork(_deform_cfg(cfg, deformable), ctx.extent).to(dev) if deformable else None
    background = make_background(cfg, mod.channels, dev)
    start = 0
    ckpt = load_checkpoint(ctx.checkpoint_path(2), ctx.stage2_sha)
    if ckpt is not None:
        g = GaussianSet.from_state_dict(ckpt["gaussians"])
        if deform is not None and ckpt.get("deform") is not None:
            deform.load_state_dict(ckpt["deform"])
        if background is not None and ckpt.get("background") is not None:
            background.load_state_dict(ckpt["background"])
        start = int(ckpt["iteration"])
    for p in g.params.values():
        p.data = p.data.to(dev)
    opt = make_optimizer(g, stage2_lrs(cfg, g, ctx.extent))
    dopt = torch.optim.Adam(deform.parameters(), lr=cfg.deform.lr_init) if deform is not None else None
    bopt = torch.optim.Adam(background.parameters(), lr=cfg.lr.background) if background is not None else None
    if ckpt is not None:
        opt.load_state_dict(ckpt["optimizer"])
        if dopt is not None and ckpt.get("deform_optimizer") is not None:
            dopt.load_state_dict(ckpt["deform_optimizer"])
        if bopt is not None and ckpt.get("background_optimizer") is not None:
            bopt.load_state_dict(ckpt["background_optimizer"])
        if ckpt.get("done"):
            ctx.log_line(f"stage 2: resumed finished stage from {ctx.checkpoint_path(2)}")
            return Stage2Result(g, deform, color, background)
    strategy = DensifyStrategy(s2.densify, ("opacity",), ctx.extent)
    idx = mod.indices("train")
    views = views_of(mod, idx, dev)
    images = torch.as_tensor(mod.images[idx], device=dev)
    total = s2.iterations

    def payload(it: int, done: bool) -> dict:
        return {"stage": 2, "iteration": it, "done": done, "config_sha256": ctx.stage2_sha,
                "gaussians": g.state_dict(), "optimizer": opt.state_dict(),
                "deform": deform.state_dict() if deform is not None else None,
                "deform_optimizer": dopt.state_dict() if dopt is not None else None,
                "background": background.state_dict() if background is not None else None,
                "background_optimizer": bopt.state_dict() if bopt is not None else None}

    bar = tqdm(range(start + 1, total + 1), desc="stage 2", disable=not cfg.progress, leave=False)
    for it in bar:
        for group in opt.param_groups:
            if group["name"] == "means":
                group["lr"] = exp_lr(it, total, cfg.lr.means_init * ctx.extent, cfg.lr.means_final * ctx.extent)
        k = int(torch.randint(len(views), (1,), generator=ctx.generator))
        view = views[k]
        deform_on = deform is not None and it > cfg.deform.warmup_iterations
        placed = place_deformed(g, deform, view.time, ctx.center, deform_on)
        cols, is_sh = colors_for(g, color)
        degree = min(cfg.sh_degree, (it - 1) // max(cfg.sh_increase_every, 1)) if is_sh else None
        out = render(view, [(placed, torch.sigmoid(g["opacity"]), cols)], degree, background)
        loss = cfg.loss.render * render_loss(out.colors[0], images[k], cfg.loss.dssim)
        try:
            check_finite(2, it, [("loss.render", loss)])
            loss.backward()
            check_finite(2, it, grads_of("gaussians", g.params) + _background_grads("background", background))
        except NaNDetected:
            save_checkpoint(ctx.out / "checkpoints" / "stage2_nan.pt", payload(it - 1, False))
            raise
        if out.means2d.grad is not None:
            strategy.accumulate(out.means2d.grad[0], out.radii[0], view.width, view.height)
        opt.step()
        opt.zero_grad(set_to_none=True)
        if dopt is not None:
            for group in dopt.param_groups:
                group["lr"] = exp_lr(it, total, cfg.deform.lr_init, cfg.deform.lr_final)
            if deform_on:
                dopt.step()
            dopt.zero_grad(set_to_none=True)
        if bopt is not None:
            bopt.step()
            bopt.zero_grad(set_to_none=True)
        try:
            check_finite(2, it, [(f"gaussians.{k}", p) for k, p in g.params.items()])
        except NaNDetected:
            save_checkpoint(ctx.out / "checkpoints" / "stage2_nan.pt", payload(it, False))
            raise
        strategy.step(it, g, opt, ctx.generator)
        if it % cfg.log_every == 0 or it == total:
            due = test_psnr is not None and it % cfg.stage3.test_every == 0
            tp = test_psnr(g, deform, background, it) if due else None
            ctx.log.write({"stage": 2, "iteration": it, "n_gaussians": g.n, "loss": float(loss.detach()),
                           f"render_{'thermal' if color == 'thermal' else 'rgb'}": float(loss.detach()),
                           "test_psnr": tp})
            bar.set_postfix(loss=f"{float(loss.detach()):.4f}", n=g.n)
        if cfg.checkpoint_every and it % cfg.checkpoint_every == 0 and it < total:
            save_checkpoint(ctx.checkpoint_path(2), payload(it, False))
    save_checkpoint(ctx.checkpoint_path(2), payload(total, True))
    return Stage2Result(g, deform, color, background)


def _background_grads(prefix: str, background: EnvironmentBackground | None) -> list[tuple[str, torch.Tensor | None]]:
    return [] if background is None else [(f"{prefix}.coeffs.grad", background.coeffs.grad)]


def _deform_cfg(cfg: TrainConfig, deformable: bool) -> DeformConfig:
    """The deformable-3dgs baseline deforms rotation and scale too, as Deformable 3DGS does."""
    return replace(cfg.deform, predict_rotation_scale=deformable and cfg.mode == "deformable-3dgs")
