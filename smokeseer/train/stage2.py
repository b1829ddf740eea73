"""Stage 2: vanilla 3DGS on one modality (thermal for SmokeSeer: smoke barely touches LWIR, so
thermal images reveal the geometry). With a deformation network the same problem is the
Deformable-3DGS backbone used by the ``deformable-3dgs`` baseline."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np
import torch

from scenes.scene import ModalityData
from smokeseer.config import DeformConfig, TrainConfig, at_iteration
from smokeseer.model.background import EnvironmentBackground
from smokeseer.model.deform import DeformNetwork
from smokeseer.model.gaussians import DensifyStrategy, GaussianSet, make_optimizer
from smokeseer.model.optim import Adam
from smokeseer.model.scene import View, add_rgb_sh, init_gaussians, make_view, place_deformed, render, sh_coeffs
from smokeseer.train.loop import IterationOutput, StageProblem, StageSchedule, run_stage
from smokeseer.train.losses import render_loss
from smokeseer.train.util import RunContext, grads_of, state_or_none, step_optimizers


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
    return EnvironmentBackground(channels, cfg.background_sh_degree, device)


def clear_pixel_weights(cfg: TrainConfig, mod: ModalityData, idx: list[int], device: torch.device
                        ) -> torch.Tensor | None:
    """Per training view ``idx`` of ``mod``, the weight of each pixel's gradient into the learned
    environment: 1 − Stage 1's smoke mask on the RGB frames under ``background_from=clear-pixels``;
    None (every pixel in full) otherwise, on the thermal frames, and where the frames carry no
    mask (no smoke marked)."""
    if cfg.background_from != "clear-pixels" or mod.name == "thermal" or mod.masks is None:
        return None
    return clear_weights(mod.masks[idx], device)


def clear_weights(masks: np.ndarray, device: torch.device) -> torch.Tensor:
    """1 − Stage 1's smoke masks, clipped to [0, 1]: how clear of smoke each pixel is."""
    return 1.0 - torch.as_tensor(np.clip(masks, 0.0, 1.0), dtype=torch.float32, device=device)


def draw_index(generator: torch.Generator, n: int) -> int:
    """A uniformly drawn training-view index from a view-order stream (a seeded CPU generator)."""
    return int(torch.randint(n, (1,), generator=generator, device=generator.device))


Stage2HeldoutPsnr = Callable[[GaussianSet, DeformNetwork | None, EnvironmentBackground | None, int],
                             dict[str, float | None] | None]


class Stage2Problem(StageProblem):
    """Fit Gaussians to one modality's training frames with the 3DGS recipe (L1 + D-SSIM,
    densification, opacity reset, SH degree schedule)."""

    stage = 2
    name = "stage 2"

    def __init__(self, ctx: RunContext, mod: ModalityData, init_points: np.ndarray, deformable: bool,
                 heldout_psnr: Stage2HeldoutPsnr | None, checkpoint: str = "stage2") -> None:
        cfg, dev = ctx.cfg, ctx.device
        self.ctx, self.cfg, self.heldout_fn, self.checkpoint = ctx, cfg, heldout_psnr, checkpoint
        self.color = "thermal" if mod.name == "thermal" else "rgb"
        tensors = init_gaussians(init_points, cfg.stage2.init_opacity, cfg.stage2.init_scale_max * ctx.extent, dev)
        if self.color == "thermal":
            tensors["thermal"] = torch.zeros((len(init_points), 1), device=dev)
        else:
            add_rgb_sh(tensors, cfg.sh_degree)
        self.g = GaussianSet(tensors)
        self.deform = None
        if deformable:
            with ctx.seeded_torch("stage2.deform"):
                self.deform = DeformNetwork(_deform_cfg(cfg, deformable), ctx.extent, dev)
        self.views_stream, self.splits_stream = (ctx.stream(f"stage2.{mod.name}.{part}") for part in ("views", "splits"))
        self.streams = {f"stage2.{mod.name}.views": self.views_stream, f"stage2.{mod.name}.splits": self.splits_stream}
        self.background = make_background(cfg, mod.channels, dev)
        self.optimizer = make_optimizer(self.g, stage2_lrs(cfg, self.g, ctx.extent))
        self.deform_optimizer = (Adam(self.deform.parameters(), lr=cfg.deform.lr_init)
                                 if self.deform else None)
        self.background_optimizer = (Adam(self.background.parameters(), lr=cfg.lr.background)
                                     if self.background else None)
        self.strategy = DensifyStrategy(cfg.stage2.densify, cfg.stage2.iterations, ("opacity",), ctx.extent)
        self.deform_warmup = at_iteration(cfg.stage2.deform_warmup, cfg.stage2.iterations)
        idx = mod.indices("train")
        self.views = views_of(mod, idx, dev)
        self.images = torch.as_tensor(mod.images[idx], device=dev)
        self.background_grad = clear_pixel_weights(cfg, mod, idx, dev) if self.background is not None else None

    def forward(self, it: int) -> IterationOutput:
        cfg = self.cfg
        k = draw_index(self.views_stream, len(self.views))
        view = self.views[k]
        deform_on = self.deform is not None and it > self.deform_warmup
        placed = place_deformed(self.g, self.deform, view.time, self.ctx.center, deform_on)
        cols, is_sh = colors_for(self.g, self.color)
        degree = min(cfg.sh_degree, (it - 1) // max(cfg.sh_increase_every, 1)) if is_sh else None
        out = render(view, [(placed, torch.sigmoid(self.g["opacity"]), cols)], degree, self.background, depth=False,
                     background_grad=None if self.background_grad is None else self.background_grad[k])
        image = out.colors[0]
        loss = render_loss(image, self.images[k], cfg.loss.dssim)
        return IterationOutput(cfg.loss.render * loss, {f"render_{self.color}": loss},
                               {"raster": out, "view": view, "deform_on": deform_on})

    def named_gradients(self) -> list[tuple[str, torch.Tensor | None]]:
        named = grads_of("gaussians", self.g.params)
        if self.background is not None:
            named.append(("background.coeffs.grad", self.background.coeffs.grad))
        if self.deform is not None:
            named += [(f"deform.{n}.grad", p.grad) for n, p in self.deform.named_parameters()]
        return named

    def named_parameters(self) -> list[tuple[str, torch.Tensor]]:
        return [(f"gaussians.{k}", p) for k, p in self.g.params.items()]

    def optimizer_step(self, it: int) -> None:
        step_optimizers(it, self.cfg.stage2.iterations, self.cfg, self.ctx.extent, [self.optimizer],
                        [self.background_optimizer], self.deform_optimizer, self.deform_warmup)

    def after_step(self, it: int, out: IterationOutput) -> None:
        raster, view = out.extra["raster"], out.extra["view"]
        if raster.means2d.grad is not None:
            self.strategy.accumulate(raster.means2d.grad[0], raster.radii[0], view.width, view.height)
        self.strategy.step(it, self.g, self.optimizer, self.splits_stream)

    def raised_loss(self, it: int) -> bool:
        return self.strategy.resets_opacity(it)

    def state(self) -> dict[str, Any]:
        return {"gaussians": self.g.state_dict(), "optimizer": self.optimizer.state_dict(),
                "deform": state_or_none(self.deform), "deform_optimizer": state_or_none(self.deform_optimizer),
                "background": state_or_none(self.background),
                "background_optimizer": state_or_none(self.background_optimizer)}

    def load_state(self, payload: dict[str, Any]) -> None:
        dev = self.ctx.device
        self.g = GaussianSet({k: v.to(dev) for k, v in payload["gaussians"].items()})
        self.optimizer = make_optimizer(self.g, stage2_lrs(self.cfg, self.g, self.ctx.extent))
        self.optimizer.load_state_dict(payload["optimizer"])
        for module, opt, key in ((self.deform, self.deform_optimizer, "deform"),
                                 (self.background, self.background_optimizer, "background")):
            if module is not None and payload.get(key) is not None:
                module.load_state_dict(payload[key])
                opt.load_state_dict(payload[f"{key}_optimizer"])

    def log_row(self, it: int, out: IterationOutput, heldout: dict[str, float | None] | None) -> dict[str, Any] | None:
        if self.checkpoint != "stage2":
            return None  # a second Stage 2 (the RGB surface of a two-surface run) keeps train_log.csv one row per iteration
        row: dict[str, Any] = {"stage": 2, "iteration": it, "n_gaussians": self.g.n,
                               "loss": float(out.loss.detach()), **(heldout or {})}
        row.update({n: float(v.detach()) for n, v in out.terms.items()})
        return row

    def heldout_psnr(self, it: int) -> dict[str, float | None] | None:
        return None if self.heldout_fn is None else self.heldout_fn(self.g, self.deform, self.background, it)

    def result(self) -> Stage2Result:
        return Stage2Result(self.g, self.deform, self.color, self.background)


def train_stage2(ctx: RunContext, mod: ModalityData, init_points: np.ndarray, deformable: bool,
                 heldout_psnr: Stage2HeldoutPsnr | None = None, checkpoint: str = "stage2",
                 sha: str | None = None) -> Stage2Result:
    """Stage 2 through the shared loop; resumes from checkpoints/<checkpoint>.pt. Its checkpoint is
    keyed by the Stage-2 settings only (``sha``, by default the run's), so ablations that differ in
    Stage 3 share it."""
    cfg = ctx.cfg
    problem = Stage2Problem(ctx, mod, init_points, deformable, heldout_psnr, checkpoint)
    run_stage(ctx, problem, StageSchedule(cfg.stage2.iterations, cfg.log_every, cfg.stage3.test_every,
                                          cfg.checkpoint_every, sha or ctx.stage2_sha))
    return problem.result()


def _deform_cfg(cfg: TrainConfig, deformable: bool) -> DeformConfig:
    """The deformable-3dgs baseline deforms rotation and scale too, as Deformable 3DGS does."""
    return replace(cfg.deform, predict_rotation_scale=deformable and cfg.mode == "deformable-3dgs")
