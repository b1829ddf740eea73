"""Hand-over to gsplat's CUDA rasterizer with the same outputs as the torch backend.

The subset alpha is rendered as one extra colour channel holding the 0/1 subset flag, so it comes
out of the same composite as the image. The background is composited here (not by gsplat) so the
extra channels stay background-free. gsplat clamps alpha at 0.999 where 3DGS (and our torch
backend) use 0.99, and it evaluates whole 16x16 tiles rather than our 3-sigma square; the two only
differ where a Gaussian is nearly opaque or has opacity above ~0.35 at its 3-sigma edge.
"""

from __future__ import annotations

import torch
from torch import Tensor

from smokeseer.raster.output import RADIUS_INT_MAX, RasterOutput, normalised_depth
from smokeseer.raster.projection import project_gaussians


def rasterize_gsplat(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
    viewmats: Tensor, Ks: Tensor, width: int, height: int, *, backgrounds: Tensor | None,
    near_plane: float, far_plane: float, subset_mask: Tensor | None, render_depth: bool,
    normalize_depth: bool,
) -> RasterOutput:
    """Render with ``gsplat.rasterization``; ``colors`` are plain [N, D] or per-camera [C, N, D]."""
    import gsplat

    c = viewmats.shape[0]
    d = colors.shape[-1]
    cols = colors if colors.dim() == 3 else colors[None].expand(c, -1, -1)
    if subset_mask is not None:
        flag = subset_mask.to(cols.dtype)[None, :, None].expand(c, -1, 1)
        cols = torch.cat([cols, flag], dim=-1)
    render, alphas, meta = gsplat.rasterization(
        means, quats, scales, opacities, cols, viewmats, Ks, width, height,
        near_plane=near_plane, far_plane=far_plane, eps2d=0.3, sh_degree=None, packed=False,
        render_mode="RGB+D" if render_depth else "RGB", rasterize_mode="classic",
    )
    img = render[..., :d]
    if backgrounds is not None:
        bg = backgrounds.reshape(-1, 1, 1, d) if backgrounds.dim() == 2 else backgrounds
        img = img + (1.0 - alphas) * bg
    subset = render[..., d:d + 1] if subset_mask is not None else None
    depths = None
    if render_depth:
        depths = render[..., -1:]
        if normalize_depth:
            depths = normalised_depth(depths, alphas)
    means2d = meta["means2d"]
    if means2d.requires_grad:
        means2d.retain_grad()
    # Radii and visibility as the other backends define them, for densification: gsplat's own
    # drop every Gaussian below opacity 1/255 and size the rest by an opacity-aware extent of at
    # most 3.33 sigma per axis, which changes which views count towards a Gaussian's mean
    # gradient and which Gaussians count as too big on screen.
    with torch.no_grad():
        ours = project_gaussians(means, quats, scales, viewmats, Ks, width, height, near_plane, far_plane)
    return RasterOutput(
        colors=img, alphas=alphas, depths=depths, subset_alphas=subset, means2d=means2d,
        radii=ours.radii.clamp_max(RADIUS_INT_MAX).to(torch.int32), visible=ours.visible,
    )
