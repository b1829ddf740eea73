"""Gaussian parameter containers and the 3DGS densification strategy.

A ``GaussianSet`` is a dict of per-Gaussian tensors (first dimension = Gaussian) held as
leaf Parameters, one optimizer group each. The densification strategy is separate from the
model (as in gsplat): it only reads screen-space gradients and edits rows of whatever
per-Gaussian tensors the set holds, keeping the Adam moments aligned.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from smokeseer.config import DensifyConfig
from smokeseer.model.optim import Adam

SH_C0 = 0.28209479177387814


def rgb_to_sh_dc(rgb: Tensor) -> Tensor:
    """Colour → degree-0 SH coefficient under the rasterizer's "+0.5" convention."""
    return (rgb - 0.5) / SH_C0


def logit(p: float, eps: float = 1e-6) -> float:
    """Inverse sigmoid of a probability, clamped away from 0 and 1."""
    p = min(max(float(p), eps), 1.0 - eps)
    return math.log(p) - math.log1p(-p)


def knn_log_scales(points: np.ndarray, k: int = 3) -> np.ndarray:
    """3DGS init: isotropic scale = RMS distance to the 3 nearest neighbours, as a log."""
    n = len(points)
    if n < 2:
        return np.full((n, 3), math.log(0.01))
    tree = cKDTree(points)
    d, _ = tree.query(points, k=min(k + 1, n))
    d = d[:, 1:]
    rms = np.sqrt(np.maximum((d ** 2).mean(1), 1e-14))
    return np.repeat(np.log(rms)[:, None], 3, axis=1)


class GaussianSet:
    """Per-Gaussian leaf tensors by name; ``means``, ``quats`` and ``log_scales`` always exist."""

    def __init__(self, tensors: dict[str, Tensor]) -> None:
        for key in ("means", "quats", "log_scales"):
            if key not in tensors:
                raise ValueError(f"tensors: missing {key!r}")
        n = tensors["means"].shape[0]
        for key, t in tensors.items():
            if t.shape[0] != n:
                raise ValueError(f"tensors[{key!r}]: has {t.shape[0]} rows, means has {n}")
        self.params: dict[str, torch.nn.Parameter] = {
            k: torch.nn.Parameter(v.detach().clone().float()) for k, v in tensors.items()}

    @property
    def n(self) -> int:
        return int(self.params["means"].shape[0])

    def __getitem__(self, key: str) -> torch.nn.Parameter:
        return self.params[key]

    def __contains__(self, key: str) -> bool:
        return key in self.params

    @property
    def quats(self) -> Tensor:
        q = self.params["quats"]
        return q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    def state_dict(self) -> dict[str, Tensor]:
        """Detached views of the live tensors (no copy): checkpoints serialise them, snapshots
        clone them, and a new set built from them copies on construction."""
        return {k: v.detach() for k, v in self.params.items()}


def make_optimizer(gset: GaussianSet, lrs: dict[str, float]) -> Adam:
    """One Adam group per named tensor so densification can edit the moments row-wise. The
    fused step (one kernel per tensor) is half the time of the per-op step on CPU (measured
    6 groups of 3k Gaussians: 0.22 against 0.43 ms) and computes the same update."""
    groups = [{"params": [gset.params[k]], "lr": lrs[k], "name": k} for k in gset.params]
    return Adam(groups, lr=0.0, eps=1e-15, fused=True)


def edit_rows(gset: GaussianSet, opt: Adam, fn) -> None:
    """Replace each per-Gaussian tensor by fn(tensor), and the Adam moments by fn(moment)
    with any appended rows' moments zeroed (3DGS: new Gaussians start with fresh moments)."""
    for group in opt.param_groups:
        name = group.get("name")
        if name not in gset.params:
            continue
        old = group["params"][0]
        new = torch.nn.Parameter(fn(name, old.detach()))
        state = opt.state.pop(old, None)
        if state:
            for key in ("exp_avg", "exp_avg_sq"):
                state[key] = fn(name, state[key], moment=True)
            opt.state[new] = state
        group["params"][0] = new
        gset.params[name] = new


@dataclass
class DensifyState:
    """Running statistics between densification steps."""

    grad_accum: Tensor
    count: Tensor
    max_radii: Tensor

    @classmethod
    def zeros(cls, n: int, device: torch.device) -> "DensifyState":
        return cls(torch.zeros(n, device=device), torch.zeros(n, device=device), torch.zeros(n, device=device))


class DensifyStrategy:
    """3DGS adaptive density control: clone small / split large high-gradient Gaussians,
    prune transparent and oversized ones, and periodically reset opacity, on the config's
    schedule resolved for a stage of ``iterations``."""

    def __init__(self, cfg: DensifyConfig, iterations: int, opacity_keys: tuple[str, ...],
                 scene_extent: float) -> None:
        self.cfg = cfg
        self.window = cfg.window(iterations)
        self.opacity_keys = opacity_keys
        self.extent = scene_extent
        self.state: DensifyState | None = None

    def reset(self, n: int, device: torch.device) -> None:
        self.state = DensifyState.zeros(n, device)

    def accumulate(self, means2d_grad: Tensor, radii: Tensor, width: int, height: int) -> None:
        """Add one view's screen-space gradient norms. Pixel gradients are scaled by half the
        image size to NDC units, so the 3DGS threshold (2e-4) keeps its meaning."""
        if self.state is None or self.state.grad_accum.shape[0] != means2d_grad.shape[0] \
                or self.state.grad_accum.device != means2d_grad.device:
            self.reset(means2d_grad.shape[0], means2d_grad.device)
        g = means2d_grad.detach().clone()
        g[:, 0] *= 0.5 * width
        g[:, 1] *= 0.5 * height
        seen = radii > 0
        norm = g.norm(dim=-1)
        norm = torch.where(torch.isfinite(norm), norm, torch.zeros_like(norm))
        self.state.grad_accum += torch.where(seen, norm, torch.zeros_like(norm))
        self.state.count += seen.float()
        self.state.max_radii = torch.maximum(self.state.max_radii, radii.detach().float())

    def _opacity(self, gset: GaussianSet) -> Tensor:
        vals = [torch.sigmoid(gset[k].detach()) for k in self.opacity_keys if k in gset]
        return torch.stack(vals).max(0).values

    def step(self, it: int, gset: GaussianSet, opt: Adam,
             generator: torch.Generator) -> dict[str, int]:
        """Run densification/pruning/reset if ``it`` (1-based) is on the schedule."""
        c = self.window
        report = {"cloned": 0, "split": 0, "pruned": 0}
        if not self._active(it):
            return report
        if it % c.every == 0 and self.state is not None and self.state.count.numel() == gset.n:
            report = self._densify_and_prune(gset, opt, generator, prune_big=self._prunes_big(it))
            self.reset(gset.n, gset["means"].device)
        if self.resets_opacity(it):
            self.reset_opacity(gset, opt)
        return report

    def _active(self, it: int) -> bool:
        c = self.window
        return c.every > 0 and c.start <= it <= c.stop

    def resets_opacity(self, it: int) -> bool:
        """Whether ``step`` resets the opacities at iteration ``it``."""
        reset = self.window.opacity_reset_every
        return self._active(it) and bool(reset) and it % reset == 0

    def _prunes_big(self, it: int) -> bool:
        """3DGS prunes oversized Gaussians only after the first opacity reset."""
        reset = self.window.opacity_reset_every
        return bool(reset) and it > reset

    def reset_opacity(self, gset: GaussianSet, opt: Adam) -> None:
        """3DGS: clamp opacities to ≤ 0.01 so floaters must earn their opacity back."""
        cap = logit(0.01)

        def fn(name: str, t: Tensor, moment: bool = False) -> Tensor:
            if name in self.opacity_keys:
                return torch.zeros_like(t) if moment else torch.clamp_max(t, cap)
            return t
        edit_rows(gset, opt, fn)

    def _densify_and_prune(self, gset: GaussianSet, opt: Adam,
                           generator: torch.Generator, prune_big: bool) -> dict[str, int]:
        c = self.cfg
        assert self.state is not None
        dev = gset["means"].device
        grads = self.state.grad_accum / self.state.count.clamp_min(1.0)
        max_scale = gset["log_scales"].detach().exp().max(-1).values
        hot = grads >= c.grad_threshold
        room = max(c.max_gaussians - gset.n, 0)
        small = max_scale <= c.percent_dense * self.extent
        if c.under_cap == "gradient" and int(hot.sum()) > room:
            # the largest mean gradients first; a stable sort keeps index order among equals
            ranked = torch.sort(torch.where(hot, grads, torch.full_like(grads, -1.0)), descending=True, stable=True)[1]
            hot = torch.zeros_like(hot).index_fill_(0, ranked[:room], True)
        clone_idx = torch.nonzero(hot & small).squeeze(-1)[:room]
        room -= clone_idx.numel()
        split_idx = torch.nonzero(hot & ~small).squeeze(-1)[: room]
        n_split = split_idx.numel()
        if clone_idx.numel() or n_split:
            new_pos = self._split_positions(gset, split_idx, generator)
            shrink = math.log(1.6)

            def grow(name: str, t: Tensor, moment: bool = False) -> Tensor:
                if moment:
                    extra = torch.zeros((clone_idx.numel() + 2 * n_split,) + t.shape[1:], dtype=t.dtype,
                                        device=t.device)
                    return torch.cat([t, extra])
                cloned = t[clone_idx]
                split = t[split_idx]
                if name == "means":
                    split_a, split_b = new_pos[0], new_pos[1]
                elif name == "log_scales":
                    split_a = split_b = split - shrink
                else:
                    split_a = split_b = split
                return torch.cat([t, cloned, split_a, split_b])
            edit_rows(gset, opt, grow)
        n_after = gset.n
        prune = torch.zeros(n_after, dtype=torch.bool, device=dev)
        prune[split_idx] = True
        opac = self._opacity(gset)
        prune |= opac < c.prune_opacity
        if prune_big:
            radii = torch.cat([self.state.max_radii,
                               torch.zeros(n_after - self.state.max_radii.numel(), device=dev)])
            prune |= radii > c.screen_size_threshold
            prune |= gset["log_scales"].detach().exp().max(-1).values > 0.1 * self.extent
        if prune.all():
            prune[opac.argmax()] = False
        if prune.any():
            keep = ~prune

            def select(name: str, t: Tensor, moment: bool = False) -> Tensor:
                return t[keep]
            edit_rows(gset, opt, select)
        return {"cloned": int(clone_idx.numel()), "split": int(n_split), "pruned": int(prune.sum())}

    @staticmethod
    def _split_positions(gset: GaussianSet, idx: Tensor, generator: torch.Generator) -> Tensor:
        """Two samples from each split Gaussian's own distribution (3DGS). The normal draws come
        from the stage's CPU split stream (the same draws on every device) and move to the means."""
        means = gset["means"].detach()[idx]
        if idx.numel() == 0:
            return means.new_zeros((2, 0, 3))
        scales = gset["log_scales"].detach()[idx].exp()
        q = gset.quats.detach()[idx]
        rot = quat_to_rotmat(q)
        out = []
        for _ in range(2):
            z = torch.randn(idx.numel(), 3, generator=generator, device=generator.device).to(scales.device) * scales
            out.append(means + torch.einsum("nij,nj->ni", rot, z))
        return torch.stack(out)


def quat_to_rotmat(q: Tensor) -> Tensor:
    """Unit wxyz quaternions → rotation matrices."""
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(q.shape[:-1] + (3, 3))
