"""Dense all-pairs reference rasterizer (every Gaussian x every pixel), for tests and benchmarks.

Written independently of ``smokeseer.raster``: rotations come from quaternion sandwich products,
covariances from explicit matrix products, conics from ``torch.linalg.inv`` and radii from
``torch.linalg.eigvalsh``; transmittance is a cumulative product over all Gaussians sorted by
depth. It applies the same cut-off rules (3-sigma square, alpha >= 1/255, alpha <= 0.99, stop
before T < 1e-4), so the fast backend must agree with it to rounding error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
import torch
from torch import Tensor


@dataclass
class DenseOutput:
    """Reference images [C, H, W, *] and per-Gaussian projection data [C, N, *]."""

    colors: Tensor
    alphas: Tensor
    depths: Tensor
    subset_alphas: Tensor | None
    means2d: Tensor
    radii: Tensor
    visible: Tensor


def _hamilton(p: Tensor, q: Tensor) -> Tensor:
    pw, px, py, pz = p.unbind(-1)
    qw, qx, qy, qz = q.unbind(-1)
    return torch.stack([
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ], dim=-1)


def rotation_from_quaternion(quats: Tensor) -> Tensor:
    """Rotation matrices whose columns are q e_i q^* for unit basis vectors e_i."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    conj = q * q.new_tensor([1.0, -1.0, -1.0, -1.0])
    cols = []
    for i in range(3):
        e = torch.zeros_like(q)
        e[..., i + 1] = 1.0
        cols.append(_hamilton(_hamilton(q, e), conj)[..., 1:])
    return torch.stack(cols, dim=-1)


@dataclass
class DenseProjection:
    """One camera's projected Gaussians, already in front-to-back order (index ``order``)."""

    order: Tensor  # [N] original indices, sorted by view depth
    means2d: Tensor  # [N, 2] (original order)
    conic: Tensor  # [N, 2, 2] sorted
    opacity: Tensor  # [N] sorted
    depth: Tensor  # [N] sorted
    radius: Tensor  # [N] sorted
    visible: Tensor  # [N] sorted


def dense_project(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, w2c: Tensor, k: Tensor,
    width: int, height: int, near_plane: float, far_plane: float, means2d_offset: Tensor | None = None,
) -> DenseProjection:
    """EWA projection written from the matrices: cov2 = J W R S S^T R^T W^T J^T + 0.3 I."""
    n = means.shape[0]
    rot = rotation_from_quaternion(quats)
    cov3 = rot @ torch.diag_embed(scales**2) @ rot.transpose(-1, -2)
    pc = means @ w2c[:3, :3].T + w2c[:3, 3]
    z = pc[:, 2]
    ok_depth = (z >= near_plane) & (z <= far_plane)
    zs = torch.where(ok_depth, z, torch.ones_like(z))
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    lim_x = (width / 2) / fx * 0.3
    lim_y = (height / 2) / fy * 0.3
    tx = zs * torch.clamp(pc[:, 0] / zs, min=-(cx / fx + lim_x), max=(width - cx) / fx + lim_x)
    ty = zs * torch.clamp(pc[:, 1] / zs, min=-(cy / fy + lim_y), max=(height - cy) / fy + lim_y)
    jac = torch.zeros(n, 2, 3, dtype=means.dtype, device=means.device)
    jac[:, 0, 0] = fx / zs
    jac[:, 0, 2] = -fx * tx / zs**2
    jac[:, 1, 1] = fy / zs
    jac[:, 1, 2] = -fy * ty / zs**2
    cov_cam = w2c[:3, :3] @ cov3 @ w2c[:3, :3].T
    cov2 = jac @ cov_cam @ jac.transpose(1, 2) + 0.3 * torch.eye(2, dtype=means.dtype, device=means.device)
    conic = torch.linalg.inv(cov2)
    with torch.no_grad():
        eig = torch.linalg.eigvalsh(cov2)
        mid = 0.5 * (cov2[:, 0, 0] + cov2[:, 1, 1])
        radius = torch.ceil(3.0 * torch.sqrt(mid + torch.clamp_min(eig[:, 1] - mid, 0.1)))
    m2 = torch.stack([fx * pc[:, 0] / zs + cx, fy * pc[:, 1] / zs + cy], dim=-1)
    if means2d_offset is not None:
        m2 = m2 + means2d_offset
    md = m2.detach()
    vis = ok_depth & (md[:, 0] + radius > 0) & (md[:, 0] - radius < width) & (md[:, 1] + radius > 0) & (md[:, 1] - radius < height)
    order = torch.argsort(z.detach(), stable=True)
    return DenseProjection(order=order, means2d=m2, conic=conic[order], opacity=opacities[order],
                           depth=z[order], radius=radius[order], visible=vis[order])


def dense_composite(proj: DenseProjection, centres: Tensor, values: Tensor) -> tuple[Tensor, Tensor]:
    """Blend ``values`` [N, V] (sorted order) at pixel ``centres`` [P, 2]: (sum w*v [P, V], alpha [P])."""
    d = centres[:, None, :] - proj.means2d[proj.order][None, :, :]  # [P, N, 2] pixel minus centre
    q = proj.conic
    sigma = 0.5 * (q[:, 0, 0] * d[..., 0] ** 2 + q[:, 1, 1] * d[..., 1] ** 2) + q[:, 0, 1] * d[..., 0] * d[..., 1]
    alpha = torch.clamp(proj.opacity * torch.exp(-sigma), max=0.99)
    inside = (d.detach().abs() <= proj.radius[None, :, None]).all(-1)
    use = proj.visible[None, :] & inside & (sigma >= 0) & (alpha >= 1.0 / 255.0)
    a = torch.where(use, alpha, torch.zeros_like(alpha))
    t_after = torch.cumprod(1.0 - a, dim=1)
    t_before = torch.cat([torch.ones_like(t_after[:, :1]), t_after[:, :-1]], dim=1)
    wgt = a * t_before * (t_after >= 1e-4)
    return wgt @ values, wgt.sum(1)


def pixel_centres(width: int, height: int, like: Tensor) -> Tensor:
    """Row-major pixel centres (x + 0.5, y + 0.5), [H*W, 2]."""
    ys, xs = torch.meshgrid(torch.arange(height, dtype=like.dtype, device=like.device),
                            torch.arange(width, dtype=like.dtype, device=like.device), indexing="ij")
    return torch.stack([xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5], dim=-1)


def dense_rasterize(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
    viewmats: Tensor, Ks: Tensor, width: int, height: int, *,
    near_plane: float = 0.01, far_plane: float = 1e10, backgrounds: Tensor | None = None,
    subset_mask: Tensor | None = None, means2d_offset: Tensor | None = None, pixels: slice | None = None,
) -> DenseOutput:
    """Render by evaluating every Gaussian at every pixel centre. ``colors``: [N, D] or [C, N, D].

    ``means2d_offset`` [C, N, 2] (zeros) is added to the projected centres so a test can read the
    screen-space gradient from its ``.grad``. ``pixels`` renders only that slice of the row-major
    pixels; images are then [C, P, *].
    """
    centres = pixel_centres(width, height, means)
    img_shape = (height, width) if pixels is None else (-1,)
    if pixels is not None:
        centres = centres[pixels]
    outs: dict[str, list[Tensor]] = {k: [] for k in ("colors", "alphas", "depths", "subset", "m2", "radii", "vis")}
    for c in range(viewmats.shape[0]):
        proj = dense_project(means, quats, scales, opacities, viewmats[c], Ks[c], width, height, near_plane,
                             far_plane, None if means2d_offset is None else means2d_offset[c])
        col_c = colors[c] if colors.dim() == 3 else colors
        vals = [col_c[proj.order], proj.depth[:, None]]
        if subset_mask is not None:
            vals.append(subset_mask[proj.order].to(col_c.dtype)[:, None])
        summed, acc = dense_composite(proj, centres, torch.cat(vals, dim=1))
        dcol = col_c.shape[-1]
        img = summed[:, :dcol].reshape(*img_shape, dcol)
        acc = acc.reshape(*img_shape, 1)
        if backgrounds is not None:
            bg = backgrounds[c] if backgrounds.dim() == 2 else backgrounds
            img = img + (1 - acc) * bg
        outs["colors"].append(img)
        outs["alphas"].append(acc)
        outs["depths"].append(summed[:, dcol].reshape(*img_shape, 1))
        if subset_mask is not None:
            outs["subset"].append(summed[:, dcol + 1].reshape(*img_shape, 1))
        inv = torch.argsort(proj.order)
        vis = proj.visible[inv]
        outs["m2"].append(torch.where(vis[:, None], proj.means2d, torch.zeros_like(proj.means2d)))
        outs["radii"].append(torch.where(vis, proj.radius[inv], torch.zeros_like(proj.radius)).to(torch.int32))
        outs["vis"].append(vis)
    return DenseOutput(
        colors=torch.stack(outs["colors"]),
        alphas=torch.stack(outs["alphas"]),
        depths=torch.stack(outs["depths"]),
        subset_alphas=torch.stack(outs["subset"]) if subset_mask is not None else None,
        means2d=torch.stack(outs["m2"]),
        radii=torch.stack(outs["radii"]),
        visible=torch.stack(outs["vis"]),
    )


def dense_loss_backward(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
    viewmats: Tensor, Ks: Tensor, width: int, height: int, weights: Tensor, *,
    pixel_chunk: int = 256, chunks: list[int] | None = None,
) -> float:
    """Forward + backward of sum(weights * [colors, alphas, depths]) with memory ~ pixel_chunk x N.

    Each camera is projected once; its projected quantities are detached into leaves, every pixel
    chunk is composited and back-propagated into those leaves, and the accumulated leaf gradients
    are then pushed through the projection once: exactly one big backward, in bounded memory.
    ``chunks`` restricts the work to those chunk indices (the benchmark times a subset).
    Plain colours [N, D] only. Returns the loss over the chunks processed.
    """
    flat_w = weights.reshape(weights.shape[0], height * width, -1)
    centres = pixel_centres(width, height, means)
    n_chunks = -(-height * width // pixel_chunk)
    total = 0.0
    for c in range(viewmats.shape[0]):
        proj = dense_project(means, quats, scales, opacities, viewmats[c], Ks[c], width, height, 0.01, 1e10)
        vals = torch.cat([colors[proj.order], proj.depth[:, None]], dim=1)
        diff = [proj.means2d, proj.conic, proj.opacity, vals]
        leaves = [t.detach().requires_grad_(True) for t in diff]
        leaf_proj = DenseProjection(proj.order, leaves[0], leaves[1], leaves[2], proj.depth, proj.radius, proj.visible)
        for i in range(n_chunks) if chunks is None else chunks:
            part = slice(i * pixel_chunk, (i + 1) * pixel_chunk)
            summed, acc = dense_composite(leaf_proj, centres[part], leaves[3])
            d = colors.shape[-1]
            out = torch.cat([summed[:, :d], acc[:, None], summed[:, d:]], dim=1)
            loss = (out * flat_w[c, part]).sum()
            loss.backward()
            total += float(loss.detach())
        pairs = [(t, leaf.grad if leaf.grad is not None else torch.zeros_like(t))
                 for t, leaf in zip(diff, leaves) if t.requires_grad]
        if pairs:
            torch.autograd.backward([t for t, _ in pairs], [g for _, g in pairs])
    return total


CPU_BACKENDS = ("cpu", "torch")


@pytest.fixture(scope="module", params=CPU_BACKENDS)
def every_cpu_backend(request: pytest.FixtureRequest):
    """Runs a test module once per CPU backend by pointing ``backend='auto'`` on CPU tensors at it.

    Import it into a test module and mark the module ``pytest.mark.usefixtures("every_cpu_backend")``.
    """
    from smokeseer.raster import api

    original = api._resolve_backend

    def resolve(backend: str, device: torch.device) -> str:
        return request.param if backend == "auto" and device.type == "cpu" else original(backend, device)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(api, "_resolve_backend", resolve)
        yield request.param


def random_scene(seed: int, n: int, c: int = 2, width: int = 40, height: int = 32, d: int = 3,
                 dtype: torch.dtype = torch.float64, spread: float = 0.8, scale: tuple[float, float] = (0.005, 0.15)):
    """Gaussians in front of C cameras that look at the origin from slightly different poses."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g, dtype=dtype) * spread
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = torch.rand(n, 3, generator=g, dtype=dtype) * (scale[1] - scale[0]) + scale[0]
    opac = torch.rand(n, generator=g, dtype=dtype)
    colors = torch.rand(n, d, generator=g, dtype=dtype)
    viewmats = torch.eye(4, dtype=dtype).repeat(c, 1, 1)
    for i in range(c):
        ang = 0.25 * i
        viewmats[i, :3, :3] = torch.tensor([[math.cos(ang), 0, -math.sin(ang)], [0, 1, 0],
                                             [math.sin(ang), 0, math.cos(ang)]], dtype=dtype)
        viewmats[i, :3, 3] = torch.tensor([0.1 * i, -0.05 * i, 4.0], dtype=dtype)
    f = 1.2 * width
    ks = torch.tensor([[f, 0, width / 2 + 0.3], [0, f * 1.1, height / 2 - 0.2], [0, 0, 1]], dtype=dtype).repeat(c, 1, 1)
    return means, quats, scales, opac, colors, viewmats, ks, width, height
