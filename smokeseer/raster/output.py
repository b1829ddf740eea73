"""What a render returns, shared by every backend (``smokeseer.raster.api`` picks one)."""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor

RADIUS_INT_MAX = 2**30  # radii of enormous footprints saturate here instead of overflowing int32

DEPTH_ALPHA_EPS = 1e-6  # below this accumulated alpha, normalised depth is reported as 0


@dataclass
class RasterOutput:
    """Rendered images for C cameras plus the per-Gaussian data densification needs."""

    colors: Tensor  # [C, H, W, D] background composited in
    alphas: Tensor  # [C, H, W, 1] accumulated alpha
    depths: Tensor | None  # [C, H, W, 1] expected view-space z (alpha-weighted; /alpha if normalised)
    subset_alphas: Tensor | None  # [C, H, W, 1] accumulated alpha of subset_mask Gaussians, same pass
    means2d: Tensor  # [C, N, 2] pixel centres; retains its grad for densification; any value where gsplat culled
    radii: Tensor  # [C, N] int32, 0 where culled
    visible: Tensor  # [C, N] bool
    n_pairs: int = -1  # blended (Gaussian, pixel) pairs (cpu and torch backends; -1 from gsplat)
    rest_depths: Tensor | None = None  # [C, H, W, 1] depth of the Gaussians outside subset_mask alone
    rest_alphas: Tensor | None = None  # [C, H, W, 1] their alpha, composited without the subset


def normalised_depth(depths: Tensor, alphas: Tensor) -> Tensor:
    """Alpha-weighted depth divided by alpha: the expected depth of what the pixel sees, 0 where
    almost nothing is seen (alpha below DEPTH_ALPHA_EPS)."""
    ok = alphas > DEPTH_ALPHA_EPS
    return torch.where(ok, depths / torch.where(ok, alphas, torch.ones_like(alphas)), torch.zeros_like(depths))


def box_filtered(out: RasterOutput, factor: int) -> RasterOutput:
    """Each block of ``factor`` × ``factor`` pixels of a supersampled render (``View.supersampled``)
    averaged into one pixel: a sensor pixel that integrates what falls on its area, where one
    sample at its centre would see a Gaussian far smaller than the pixel dilated to the pixel's
    size. Colours and alphas are averaged; depths, normalised as the model's renders give them, are
    averaged by alpha, so that each is still the depth of what its pixel sees. The per-Gaussian
    fields stay in sub-pixel units."""
    if factor == 1:
        return out

    def pool(x: Tensor | None) -> Tensor | None:
        return None if x is None else F.avg_pool2d(x.permute(0, 3, 1, 2), factor).permute(0, 2, 3, 1)

    def depth(d: Tensor | None, a: Tensor | None) -> Tensor | None:
        return None if d is None or a is None else normalised_depth(pool(d * a), pool(a))

    return replace(out, colors=pool(out.colors), alphas=pool(out.alphas), depths=depth(out.depths, out.alphas),
                   subset_alphas=pool(out.subset_alphas), rest_depths=depth(out.rest_depths, out.rest_alphas),
                   rest_alphas=pool(out.rest_alphas))
