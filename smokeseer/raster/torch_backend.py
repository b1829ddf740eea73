"""Pure-PyTorch sparse rasterizer: work and memory scale with the (Gaussian, pixel) pairs touched.

Algorithm (vectorised; the only Python loop is over bounded chunks of Gaussians):
1. Without autograd, walk the visible Gaussians front to back (per camera) in chunks of at most
   ``PAIR_CHUNK`` candidate pairs. Each chunk enumerates the pixels whose centres lie in each
   Gaussian's 3-sigma square and keeps pairs with alpha >= 1/255. Within the chunk, pairs are
   sorted by (pixel, depth); a per-pixel running log-transmittance carried across chunks plus a
   segmented cumulative sum of log(1 - alpha) gives each pair's transmittance, and pairs at or
   after the one that would take T below 1e-4 are dropped, exactly as 3DGS stops a pixel. So the
   pairs kept (and the memory) grow with the pairs actually blended, even in dense smoke.
2. With autograd, recompute alpha, transmittance (float64 segmented cumsum, so long segments
   stay exact) and blending weights on the kept pairs, sorted by (pixel, depth), and scatter
   them with one ``index_add``; PyTorch derives the backward pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from smokeseer.raster.projection import Projection

ALPHA_MAX = 0.99  # 3DGS clamps per-Gaussian alpha here
ALPHA_MIN = 1.0 / 255.0  # contributions below this are skipped
T_MIN = 1e-4  # a pixel stops before the Gaussian that would take T below this
PAIR_CHUNK = 1 << 20  # candidate pairs evaluated at once (bounds peak memory of step 1)


@dataclass
class Composite:
    """Flat per-pixel sums over all cameras: [C*H*W, ...]."""

    colors: Tensor  # [C*H*W, D] sum of w * colour
    alphas: Tensor  # [C*H*W] sum of w (= 1 - final transmittance)
    depths: Tensor | None  # [C*H*W] sum of w * z
    subset_alphas: Tensor | None  # [C*H*W] sum of w over the subset
    n_pairs: int  # blended (Gaussian, pixel) pairs
    rest_depths: Tensor | None = None  # [C*H*W] sum of w * z of the non-subset Gaussians alone
    rest_alphas: Tensor | None = None  # [C*H*W] their sum of w, composited without the subset


@dataclass
class _Footprints:
    """Flat [C*N] screen data used while enumerating pairs (no autograd)."""

    x0: Tensor
    y0: Tensor
    w: Tensor
    h: Tensor
    mx: Tensor
    my: Tensor
    conic: Tensor  # [C*N, 3]
    opacity: Tensor  # [N]


def _footprints(proj: Projection, opacities: Tensor, width: int, height: int) -> _Footprints:
    """Inclusive pixel ranges whose centres lie within the radius of each projected centre."""
    mx, my = proj.means2d.detach().reshape(-1, 2).unbind(-1)
    r = proj.radii.reshape(-1)
    x0 = torch.ceil(mx - r - 0.5).clamp(0, width)
    x1 = torch.floor(mx + r - 0.5).clamp(-1, width - 1)
    y0 = torch.ceil(my - r - 0.5).clamp(0, height)
    y1 = torch.floor(my + r - 0.5).clamp(-1, height - 1)
    return _Footprints(
        x0=x0.long(), y0=y0.long(),
        w=(x1 - x0 + 1).clamp_min(0).long(), h=(y1 - y0 + 1).clamp_min(0).long(),
        mx=mx, my=my, conic=proj.conics.detach().reshape(-1, 3), opacity=opacities.detach(),
    )


def _segment_starts(counts: Tensor) -> Tensor:
    return torch.cumsum(counts, 0) - counts


def _chunk_pairs(fp: _Footprints, ids: Tensor, n: int, width: int, height: int) -> tuple[Tensor, Tensor, Tensor]:
    """(camera*N + gaussian, flat pixel, alpha) of the pairs of Gaussians ``ids`` with alpha >= 1/255.

    Footprints expand row by row: the quadratic form's per-row terms are computed once, so a
    candidate pair costs one gather and a few flops, with no integer division.
    """
    device = ids.device
    hs = fp.h.index_select(0, ids)
    n_rows = int(hs.sum())
    row_owner = torch.repeat_interleave(torch.arange(ids.numel(), device=device), hs, output_size=n_rows)
    row_gid = ids.index_select(0, row_owner)
    row_y = fp.y0.index_select(0, row_gid) + torch.arange(n_rows, device=device) - _segment_starts(hs).index_select(0, row_owner)
    row_x0 = fp.x0.index_select(0, row_gid)
    row_w = fp.w.index_select(0, row_gid)
    q = fp.conic.index_select(0, row_gid)
    dy = fp.my.index_select(0, row_gid) - (row_y.to(q.dtype) + 0.5)
    row_terms = torch.stack([
        fp.mx.index_select(0, row_gid) - (row_x0.to(q.dtype) + 0.5),  # dx at the row's first pixel
        0.5 * q[:, 0],
        q[:, 1] * dy,
        0.5 * q[:, 2] * dy * dy,
        fp.opacity.index_select(0, row_gid % n),
    ], dim=1)
    n_pairs = int(row_w.sum())
    pair_row = torch.repeat_interleave(torch.arange(n_rows, device=device), row_w, output_size=n_pairs)
    k = torch.arange(n_pairs, device=device) - _segment_starts(row_w).index_select(0, pair_row)
    t = row_terms.index_select(0, pair_row)
    dx = t[:, 0] - k.to(t.dtype)
    sigma = (t[:, 1] * dx + t[:, 2]) * dx + t[:, 3]  # 0.5*(a dx^2 + c dy^2) + b dx dy
    alpha = torch.clamp_max(t[:, 4] * torch.exp(-sigma), ALPHA_MAX)
    keep = torch.nonzero((sigma >= 0) & (alpha >= ALPHA_MIN)).squeeze(1)
    kept_row = pair_row.index_select(0, keep)
    row_pix = (torch.div(row_gid, n, rounding_mode="floor") * height + row_y) * width + row_x0
    return (
        row_gid.index_select(0, kept_row),
        row_pix.index_select(0, kept_row) + k.index_select(0, keep),
        alpha.index_select(0, keep),
    )


def _segment_exclusive_logT(log1m: Tensor, seg_first: Tensor) -> Tensor:
    """Exclusive cumulative sum of log(1 - alpha), restarted at each segment start (float64)."""
    l64 = log1m.double()
    excl = torch.cumsum(l64, 0) - l64
    return excl - excl.index_select(0, seg_first)


def _segment_first(pix: Tensor) -> Tensor:
    """For each pair in pixel-sorted order, the index of the first pair of its pixel."""
    _, counts = torch.unique_consecutive(pix, return_counts=True)
    return torch.repeat_interleave(_segment_starts(counts), counts, output_size=pix.numel())


@torch.no_grad()
def blended_pairs(proj: Projection, opacities: Tensor, width: int, height: int) -> tuple[Tensor, Tensor]:
    """The (camera*N + gaussian, flat pixel) pairs that 3DGS blends, sorted by (pixel, depth)."""
    c_count, n = proj.depths.shape
    device = opacities.device
    n_rank = max(n, 1)
    fp = _footprints(proj, opacities, width, height)
    front_to_back = torch.argsort(proj.sort_key(), dim=1, stable=True)
    depth_rank = torch.empty_like(front_to_back).scatter_(
        1, front_to_back, torch.arange(n, device=device).expand(c_count, n).contiguous()
    ).reshape(-1)
    flat_order = (front_to_back + torch.arange(c_count, device=device)[:, None] * n).reshape(-1)
    counts = fp.w * fp.h
    flat_order = flat_order[(proj.visible.reshape(-1) & (counts > 0)).index_select(0, flat_order)]
    ends = torch.cumsum(counts.index_select(0, flat_order), 0)

    log_t = torch.zeros(c_count * height * width, dtype=torch.float64, device=device)
    keys, start = [], 0
    while start < flat_order.numel():
        done = int(ends[start - 1]) if start > 0 else 0
        stop = max(int(torch.searchsorted(ends, done + PAIR_CHUNK, right=True)), start + 1)
        gid, pix, alpha = _chunk_pairs(fp, flat_order[start:stop], n, width, height)
        start = stop
        key = pix * n_rank + depth_rank.index_select(0, gid)
        key, order = torch.sort(key)
        pix = pix.index_select(0, order)
        log1m = torch.log1p(-alpha.index_select(0, order)).double()
        log_t_after = log_t.index_select(0, pix) + _segment_exclusive_logT(log1m, _segment_first(pix)) + log1m
        keys.append(key[log_t_after >= math.log(T_MIN)])
        log_t.index_add_(0, pix, log1m)
    if not keys:
        empty = torch.zeros(0, dtype=torch.long, device=device)
        return empty, empty
    key = torch.sort(torch.cat(keys)).values
    pix = torch.div(key, n_rank, rounding_mode="floor")
    rank = key - pix * n_rank
    cam = torch.div(pix, height * width, rounding_mode="floor")
    gid = front_to_back.reshape(-1).index_select(0, cam * n + rank) + cam * n
    return gid, pix


def composite(
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
    """Front-to-back alpha compositing of projected Gaussians, differentiable through autograd.

    ``colors`` is [N, D] (shared by all cameras) or [C, N, D] (per camera, e.g. from SH). With
    ``rest_alone``, the Gaussians outside ``subset_mask`` are composited once more on their own
    (the readable reference for the compiled kernel's second stream).
    """
    c_count, n = proj.depths.shape
    d = colors.shape[-1]
    dtype = opacities.dtype
    device = opacities.device
    gid, pix = blended_pairs(proj, opacities, width, height)

    # Two tables of what a pair needs, each gathered once (each backward is one index_add).
    geom = torch.cat([proj.means2d, proj.conics, opacities[None, :, None].expand(c_count, n, 1)], dim=-1)
    values = [colors if colors.dim() == 3 else colors[None].expand(c_count, n, d),
              torch.ones(c_count, n, 1, dtype=dtype, device=device)]
    if render_depth:
        values.append(proj.depths[..., None])
    if subset_mask is not None:
        values.append(subset_mask.to(dtype)[None, :, None].expand(c_count, n, 1))
    table = torch.cat(values, dim=-1)
    mx, my, qa, qb, qc, opac = geom.reshape(c_count * n, 6).index_select(0, gid).unbind(1)
    vals = table.reshape(c_count * n, table.shape[-1]).index_select(0, gid)

    px = (pix % width).to(dtype) + 0.5
    py = torch.div(pix, width, rounding_mode="floor").remainder(height).to(dtype) + 0.5
    dx = mx - px
    dy = my - py
    sigma = 0.5 * (qa * dx * dx + qc * dy * dy) + qb * dx * dy
    alpha = torch.clamp_max(opac * torch.exp(-sigma), ALPHA_MAX)
    trans = torch.exp(_segment_exclusive_logT(torch.log1p(-alpha), _segment_first(pix))).to(dtype)
    vals = (alpha * trans)[:, None] * vals
    total = torch.zeros(c_count * height * width, vals.shape[1], dtype=dtype, device=device)
    total = total.index_add(0, pix, vals)
    rest = _rest_alone(proj, opacities, width, height, subset_mask) if rest_alone else None
    return Composite(
        colors=total[:, :d],
        alphas=total[:, d],
        depths=total[:, d + 1] if render_depth else None,
        subset_alphas=total[:, -1] if subset_mask is not None else None,
        n_pairs=int(pix.numel()),
        rest_depths=rest.depths if rest is not None else None,
        rest_alphas=rest.alphas if rest is not None else None,
    )


def _rest_alone(proj: Projection, opacities: Tensor, width: int, height: int, subset_mask: Tensor | None) -> Composite:
    """Depth and alpha of the Gaussians outside ``subset_mask``, composited without the others."""
    if subset_mask is None:
        raise ValueError("rest_alone needs a subset_mask")
    keep = ~subset_mask
    rest = Projection(
        means2d=proj.means2d[:, keep], conics=proj.conics[:, keep], depths=proj.depths[:, keep],
        radii=proj.radii[:, keep], visible=proj.visible[:, keep],
        sort_depths=proj.sort_depths[:, keep] if proj.sort_depths is not None else None,
    )
    no_colour = opacities.new_zeros((int(keep.sum()), 0))
    return composite(rest, opacities[keep], no_colour, width, height, render_depth=True, subset_mask=None)
