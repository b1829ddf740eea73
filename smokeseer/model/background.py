"""A learned environment behind the Gaussians: low-order SH over the world ray direction.

Why: 3DGS's black background is right for object captures on black, but our scenes (and
outdoor drone data) have a sky. Without an environment the only way to explain the sky is with
Gaussians, and in Stage 3 the cheapest ones are the smoke Gaussians, which the surface-only
render then lacks. An environment at infinity is shared by the composite and the surface-only
renders, so it is part of the de-smoked prediction. Low degree (2 by default) keeps it smooth:
it can model a sky gradient but not a localised object, which stays the Gaussians' job.
"""
from __future__ import annotations

import torch
from torch import Tensor, nn

from smokeseer.raster.sh import num_sh_bases, sh_basis_along, sh_sum


def ray_directions(viewmat: Tensor, K: Tensor, width: int, height: int) -> Tensor:
    """World-space directions through pixel centres [H, W, 3] for an OpenCV w2c ``viewmat``
    [4, 4] and intrinsics ``K`` [3, 3] (not normalised; ``eval_sh`` normalises)."""
    dtype, dev = viewmat.dtype, viewmat.device
    v, u = torch.meshgrid(torch.arange(height, dtype=dtype, device=dev) + 0.5,
                          torch.arange(width, dtype=dtype, device=dev) + 0.5, indexing="ij")
    cam = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], dim=-1)
    return cam @ viewmat[:3, :3]


class EnvironmentBackground(nn.Module):
    """Radiance at infinity as SH of degree ``degree`` with ``channels`` outputs, in the 3DGS
    convention (value = SH sum + 0.5, clamped at 0), so zero coefficients mean mid grey."""

    def __init__(self, channels: int, degree: int, device: torch.device) -> None:
        super().__init__()
        if not 0 <= degree <= 3:
            raise ValueError(f"background_sh_degree: must be in 0..3, got {degree}")
        self.degree = degree
        self.coeffs = nn.Parameter(torch.zeros(num_sh_bases(degree), channels, device=device))

    def basis(self, viewmat: Tensor, K: Tensor, width: int, height: int) -> Tensor:
        """The SH basis [H, W, K] of one camera's pixel rays: fixed for a fixed camera, so a
        caller that renders the same view many times can keep it (``from_basis``)."""
        return sh_basis_along(self.degree, ray_directions(viewmat, K, width, height))

    def from_basis(self, basis: Tensor) -> Tensor:
        """The environment for a camera whose ray basis is ``basis``, [H, W, channels]."""
        return (sh_sum(basis, self.coeffs) + 0.5).clamp_min(0.0)

    def forward(self, viewmat: Tensor, K: Tensor, width: int, height: int) -> Tensor:
        """The environment seen by one camera, [H, W, channels]."""
        return self.from_basis(self.basis(viewmat, K, width, height))


def composite_over(colors: Tensor, alphas: Tensor, background: Tensor) -> Tensor:
    """Put ``background`` [H, W, C] behind a render made on black: colours [1, H, W, C] are
    premultiplied, so the background shows through with weight 1 − alpha."""
    return colors + (1.0 - alphas) * background[None]
