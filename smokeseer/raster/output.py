"""What a render returns, shared by every backend (``smokeseer.raster.api`` picks one)."""
from __future__ import annotations

from dataclasses import dataclass

import torch
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
