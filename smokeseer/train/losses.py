"""Training losses. Images are [H, W, C] tensors; each prior is a separate function so modes
can switch them off one at a time (docs/method.md gives each definition and its source)."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

_SSIM_C1 = 0.01 ** 2
_SSIM_C2 = 0.03 ** 2


def _gauss_taps(device: torch.device, dtype: torch.dtype, size: int = 11, sigma: float = 1.5) -> Tensor:
    x = torch.arange(size, dtype=dtype, device=device) - size // 2
    g = torch.exp(-(x ** 2) / (2 * sigma ** 2))
    return g / g.sum()


def ssim(pred: Tensor, target: Tensor) -> Tensor:
    """Differentiable SSIM with the 3DGS convention (11×11 Gaussian σ=1.5, zero padding,
    mean over the full map).

    Why separable: the 11×11 window is the outer product of one 11-tap Gaussian and zero
    padding commutes with that split, so two 11-tap passes over the five stacked maps (x, y,
    x², y², xy) in one grouped convolution give the 2-D blur at a fifth of the cost."""
    if pred.shape != target.shape or pred.dim() != 3:
        raise ValueError(f"pred/target: need matching [H, W, C], got {tuple(pred.shape)} and {tuple(target.shape)}")
    c = pred.shape[-1]
    x = pred.permute(2, 0, 1)
    y = target.permute(2, 0, 1)
    maps = torch.cat([x, y, x * x, y * y, x * y])[None]
    g = _gauss_taps(pred.device, pred.dtype)
    blurred = F.conv2d(maps, g.view(1, 1, 1, 11).expand(5 * c, 1, 1, 11), padding=(0, 5), groups=5 * c)
    blurred = F.conv2d(blurred, g.view(1, 1, 11, 1).expand(5 * c, 1, 11, 1), padding=(5, 0), groups=5 * c)
    mx, my, bxx, byy, bxy = blurred[0].split(c)
    sxx = bxx - mx * mx
    syy = byy - my * my
    sxy = bxy - mx * my
    num = (2 * mx * my + _SSIM_C1) * (2 * sxy + _SSIM_C2)
    den = (mx * mx + my * my + _SSIM_C1) * (sxx + syy + _SSIM_C2)
    return (num / den).mean()


def render_loss(pred: Tensor, target: Tensor, dssim_weight: float = 0.2) -> Tensor:
    """3DGS photometric loss: (1 − λ)·L1 + λ·(1 − SSIM), λ = 0.2."""
    l1 = (pred - target).abs().mean()
    if dssim_weight == 0.0:
        return l1
    return (1.0 - dssim_weight) * l1 + dssim_weight * (1.0 - ssim(pred, target))


def smoke_alpha_variance(opacities: Tensor) -> Tensor:
    """Variance of the smoke Gaussians' RGB opacities: smoke is a homogeneous medium, so its
    Gaussians should share one density rather than mimic surface texture."""
    return opacities.var(unbiased=False) if opacities.numel() > 1 else opacities.sum() * 0.0


def smoke_color_variance(colors: Tensor) -> Tensor:
    """Variance across smoke Gaussians of their colours (per channel, averaged): smoke has one
    colour, set by its single-scattering albedo and the illumination."""
    return colors.var(dim=0, unbiased=False).mean() if colors.shape[0] > 1 else colors.sum() * 0.0


def monochromaticity(colors: Tensor) -> Tensor:
    """Variance across R, G, B within each smoke Gaussian: smoke scatters nearly grey."""
    return colors.var(dim=-1, unbiased=False).mean() if colors.numel() else colors.sum() * 0.0


def align_scale_shift(pred: Tensor, prior: Tensor, valid: Tensor) -> tuple[Tensor, Tensor]:
    """Least-squares (s, b) with s·prior + b ≈ pred over valid pixels, solved in closed form
    and detached: the prior's per-image scale and shift are nuisance parameters (MiDaS)."""
    p = prior[valid].double()
    q = pred.detach()[valid].double()
    n = p.numel()
    if n < 2:
        return pred.new_ones(()), pred.new_zeros(())
    a = torch.stack([torch.stack([(p * p).sum(), p.sum()]), torch.stack([p.sum(), p.new_tensor(float(n))])])
    rhs = torch.stack([(p * q).sum(), q.sum()])
    det = torch.det(a)
    if not torch.isfinite(det) or det.abs() < 1e-12 * max(float((p * p).sum()), 1.0) * n:
        return torch.ones((), dtype=pred.dtype), (q.mean() - p.mean()).to(pred.dtype)
    s, b = torch.linalg.solve(a, rhs)
    return s.to(pred.dtype), b.to(pred.dtype)


def depth_consistency(depth: Tensor, prior: Tensor, valid: Tensor) -> Tensor:
    """L1 between rendered surface depth and the scale/shift-aligned prior, averaged over valid pixels."""
    if valid.sum() < 2:
        return depth.sum() * 0.0
    s, b = align_scale_shift(depth, prior, valid)
    return (depth[valid] - (s * prior[valid] + b)).abs().mean()


def mask_alignment(smoke_alpha: Tensor, mask: Tensor, floor: float, floor_where: Tensor | None = None,
                   targets: Tensor | None = None) -> Tensor:
    """L1 between the accumulated smoke alpha and the smoke mask, where smoke alpha at or above
    ``floor`` counts as 1 inside the mask (``loss.mask_alpha_floor``; the public code's threshold is 0.4).

    Why: a mask says where smoke is, not how dense it is. A plain L1 drives smoke alpha to 1 in
    every masked pixel; where the mask covers the whole frame (the chair and brick_toy bench
    scenes) the smoke then hides the surface and the surface-only render fails (chair: 15.3 dB
    with the plain L1, 20.7 dB without the term). Outside the mask it still pulls alpha to 0.

    ``floor_where`` (like the mask, bool or a weight in [0, 1]): inside the mask but outside it, any
    alpha counts as full smoke, so only the push to zero outside the mask is left
    (``loss.mask_floor_where``); a weight w between blends the two, w × the floor's term + (1 − w) ×
    the term without it (``loss.mask_floor_meeting=trusted``).

    ``targets`` (like the mask, in [0, 1]; ``loss.mask_floor_where=estimated-bound``): inside the
    mask the alpha is pushed up to its pixel's target and never down, a floor per pixel in place of
    the one step at ``floor``."""
    if targets is not None:
        return torch.where(mask > 0.5, torch.relu(targets - smoke_alpha), (smoke_alpha - mask).abs()).mean()
    floored = (torch.where(smoke_alpha >= floor, torch.ones_like(smoke_alpha), smoke_alpha) - mask).abs()
    if floor_where is not None:  # the term without the floor: alpha counts as full smoke, 1 - mask
        w = floor_where.to(smoke_alpha.dtype)
        floored = w * floored + (1.0 - w) * (1.0 - mask).abs()
    return torch.where(mask > 0.5, floored, (smoke_alpha - mask).abs()).mean()
