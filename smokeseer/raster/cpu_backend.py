"""Compiled CPU backend: EWA projection and 16x16-tile compositing in C++, each with an analytic
backward, and SH colours (``sh_colors``), each wrapped as an autograd Function.

The projection returns the same ``Projection`` as the torch one. The compositing kernel takes one
feature table per camera, [C, N, F] = colours, then depth and the subset flag when asked, so one
pass yields every image ``rasterize`` returns.
The alpha image is 1 - T_final. Backward follows 3DGS: walk each pixel's blended Gaussians back
to front, rebuilding transmittance from the final one (kept in float64 per pixel), so no
per-pair state is stored; per-Gaussian sums use a fixed reduction order (see csrc/tile_raster.cpp).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from smokeseer.raster.extension import load_kernel
from smokeseer.raster.projection import Projection
from smokeseer.raster.torch_backend import Composite


class _Projection(torch.autograd.Function):
    """(means, quats, linear scales, viewmats) -> (means2d, conics, depths, radii, visible)."""

    @staticmethod
    def forward(ctx: Any, means: Tensor, quats: Tensor, scales: Tensor, viewmats: Tensor, ks: Tensor,
                width: int, height: int, near_plane: float, far_plane: float) -> tuple[Tensor, ...]:
        means2d, conics, depths, radii, visible, sort_depths = load_kernel().project_forward(
            means, quats, scales, viewmats, ks, width, height, near_plane, far_plane)
        ctx.save_for_backward(means, quats, scales, viewmats, ks)
        ctx.size = (width, height, near_plane, far_plane)
        ctx.mark_non_differentiable(radii, visible, sort_depths)
        return means2d, conics, depths, radii, visible, sort_depths

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, g_means2d: Tensor, g_conics: Tensor, g_depths: Tensor, _g_radii: Tensor,
                 _g_visible: Tensor, _g_sort: Tensor) -> tuple:
        g_means, g_quats, g_scales, g_viewmats = load_kernel().project_backward(
            *ctx.saved_tensors, *ctx.size, g_means2d.contiguous(), g_conics.contiguous(), g_depths.contiguous())
        return g_means, g_quats, g_scales, g_viewmats, None, None, None, None, None


def project_compiled(means: Tensor, quats: Tensor, scales: Tensor, viewmats: Tensor, ks: Tensor,
                     width: int, height: int, near_plane: float, far_plane: float) -> Projection:
    """``projection.project_gaussians`` in C++ (no gradient for ``ks``: the caller checks)."""
    means2d, conics, depths, radii, visible, sort_depths = _Projection.apply(
        means.contiguous(), quats.contiguous(), scales.contiguous(), viewmats.contiguous(),
        ks.detach().contiguous(), width, height, float(near_plane), float(far_plane))
    return Projection(means2d=means2d, conics=conics, depths=depths, radii=radii, visible=visible,
                      sort_depths=sort_depths)


class _ShColors(torch.autograd.Function):
    """(SH coefficients [N, K, D], means [N, 3], camera centres [C, 3]) -> colours [C, N, D]."""

    @staticmethod
    def forward(ctx: Any, coeffs: Tensor, means: Tensor, campos: Tensor, degree: int) -> Tensor:
        ctx.save_for_backward(coeffs, means, campos)
        ctx.degree = degree
        return load_kernel().sh_forward(coeffs, means, campos, degree)

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, g_colors: Tensor) -> tuple:
        g_coeffs, g_means = load_kernel().sh_backward(*ctx.saved_tensors, ctx.degree, g_colors.contiguous())
        return g_coeffs, g_means, None, None


def sh_colors(coeffs: Tensor, means: Tensor, campos: Tensor, degree: int) -> Tensor:
    """``raster.api.view_colors`` in C++: max(SH sum along means - campos + 0.5, 0) per camera
    (no gradient for the camera centres: the caller checks)."""
    return _ShColors.apply(coeffs.contiguous(), means.contiguous(), campos.detach().contiguous(), degree)


class _TileComposite(torch.autograd.Function):
    """(means2d, conics, opacities, feats) -> (feature image [C,H,W,F], alpha [C,H,W], pairs,
    alone feature [C*H*W], alone alpha [C*H*W]). With ``alone`` >= 0 the last feature is the
    subset flag, and the Gaussians outside the subset are also composited on their own, in the same
    walk over the tile lists, carrying feature ``alone`` (empty outputs otherwise)."""

    @staticmethod
    def forward(ctx: Any, means2d: Tensor, conics: Tensor, opacities: Tensor, feats: Tensor,
                radii: Tensor, sort_keys: Tensor, visible: Tensor, width: int, height: int,
                alone: int) -> tuple[Tensor, ...]:
        image, alpha, n_pairs, image2, alpha2, t_final, last, t_final2, last2, *bins = load_kernel().forward(
            means2d, conics, opacities, feats, radii, sort_keys, visible, width, height, alone)
        ctx.save_for_backward(t_final, last, *bins, t_final2, last2)
        ctx.shape = (means2d.shape[0], means2d.shape[1], width, height, alone)
        ctx.mark_non_differentiable(n_pairs)
        return image, alpha, n_pairs, image2, alpha2

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad_image: Tensor, grad_alpha: Tensor, _grad_pairs: Tensor, grad_image2: Tensor,
                 grad_alpha2: Tensor) -> tuple:
        cams, n, width, height, alone = ctx.shape
        *state, t_final2, last2 = ctx.saved_tensors
        g_means2d, g_conics, g_opac, g_feats = load_kernel().backward(
            cams, n, *state, grad_image.contiguous(), grad_alpha.contiguous(), t_final2, last2,
            grad_image2.contiguous(), grad_alpha2.contiguous(), alone, width, height)
        return g_means2d, g_conics, g_opac.sum(0), g_feats, None, None, None, None, None, None


def composite_tiles(
    proj: Projection,
    opacities: Tensor,
    colors: Tensor,
    width: int,
    height: int,
    *,
    render_depth: bool,
    subset_mask: Tensor | None,
    rest_alone: bool = False,
) -> Composite:
    """Front-to-back compositing with the compiled kernel; same contract as ``torch_backend.composite``.

    ``colors`` is [N, D] (shared by all cameras) or [C, N, D] (per camera, e.g. from SH). The
    rest-alone depth and alpha come from the same kernel call (a second transmittance per pixel).
    """
    if opacities.device.type != "cpu":
        raise ValueError(f"backend='cpu' needs CPU tensors, got {opacities.device}")
    c_count, n = proj.depths.shape
    d = colors.shape[-1]
    columns = [colors if colors.dim() == 3 else colors[None].expand(c_count, n, d)]
    if render_depth:
        columns.append(proj.depths[..., None])
    if subset_mask is not None:
        columns.append(subset_mask.to(opacities.dtype)[None, :, None].expand(c_count, n, 1))
    feats = torch.cat(columns, dim=-1).contiguous()
    image, alpha, n_pairs, rest_depth, rest_alpha = _TileComposite.apply(  # front to back, ties by index
        proj.means2d.contiguous(), proj.conics.contiguous(), opacities.contiguous(), feats,
        proj.radii.detach().contiguous(), proj.sort_key(), proj.visible.contiguous(), width, height,
        d if rest_alone else -1,
    )
    flat = image.reshape(c_count * height * width, -1)
    return Composite(
        colors=flat[:, :d],
        alphas=alpha.reshape(-1),
        depths=flat[:, d] if render_depth else None,
        subset_alphas=flat[:, -1] if subset_mask is not None else None,
        n_pairs=int(n_pairs),
        rest_depths=rest_depth if rest_alone else None,
        rest_alphas=rest_alpha if rest_alone else None,
    )
