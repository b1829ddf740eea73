"""One entry point for differentiable Gaussian rasterization: compiled CPU tiles, pure PyTorch, or gsplat (CUDA)."""

from __future__ import annotations

import importlib.util
from dataclasses import replace

import torch
from torch import Tensor

from smokeseer.raster.cpu_backend import composite_tiles, project_compiled, sh_colors
from smokeseer.raster.finite import first_non_finite
from smokeseer.raster.output import RADIUS_INT_MAX, RasterOutput, normalised_depth
from smokeseer.raster.projection import project_gaussians
from smokeseer.raster.sh import eval_sh, num_sh_bases
from smokeseer.raster.torch_backend import composite

BACKENDS = ("auto", "cpu", "torch", "gsplat")


def gsplat_available() -> bool:
    """True when the gsplat package can be imported (it needs CUDA to run). A folder named gsplat
    on the path without the package in it (a namespace package, no origin) does not count."""
    spec = importlib.util.find_spec("gsplat")
    return spec is not None and spec.origin is not None


def _validate(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
    viewmats: Tensor, Ks: Tensor, width: int, height: int, sh_degree: int | None,
    log_scales: bool, backgrounds: Tensor | None, near_plane: float, far_plane: float,
    subset_mask: Tensor | None, render_depth: bool, render_rest_alone: bool,
) -> None:
    """Reject malformed input with a ValueError that names the offending argument."""
    if means.dim() != 2 or means.shape[1] != 3:
        raise ValueError(f"means must be [N, 3], got {tuple(means.shape)}")
    if not means.dtype.is_floating_point:
        raise ValueError(f"means must be floating point, got {means.dtype}")
    n = means.shape[0]
    for name, t, shape in (("quats", quats, (n, 4)), ("scales", scales, (n, 3)), ("opacities", opacities, (n,))):
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} must be {list(shape)}, got {tuple(t.shape)}")
    if viewmats.dim() != 3 or viewmats.shape[1:] != (4, 4):
        raise ValueError(f"viewmats must be [C, 4, 4], got {tuple(viewmats.shape)}")
    c = viewmats.shape[0]
    if tuple(Ks.shape) != (c, 3, 3):
        raise ValueError(f"Ks must be [C, 3, 3] with C={c}, got {tuple(Ks.shape)}")
    if int(width) != width or int(height) != height or width <= 0 or height <= 0:
        raise ValueError(f"width and height must be positive integers, got {width}x{height}")
    if sh_degree is None:
        if colors.dim() != 2 or colors.shape[0] != n:
            raise ValueError(f"colors must be [N, D] when sh_degree is None, got {tuple(colors.shape)}")
    else:
        if not 0 <= sh_degree <= 3:
            raise ValueError(f"sh_degree must be in 0..3, got {sh_degree}")
        if colors.dim() != 3 or colors.shape[0] != n or colors.shape[1] < num_sh_bases(sh_degree):
            raise ValueError(
                f"colors must be [N, K>={num_sh_bases(sh_degree)}, D] for sh_degree={sh_degree}, "
                f"got {tuple(colors.shape)}"
            )
    if not (0.0 <= near_plane < far_plane):
        raise ValueError(f"need 0 <= near_plane < far_plane, got {near_plane}, {far_plane}")
    d = colors.shape[-1]
    if backgrounds is not None and tuple(backgrounds.shape) not in ((d,), (c, d)):
        raise ValueError(f"backgrounds must be [{d}] or [{c}, {d}], got {tuple(backgrounds.shape)}")
    if subset_mask is not None and (subset_mask.dtype != torch.bool or tuple(subset_mask.shape) != (n,)):
        raise ValueError(f"subset_mask must be a bool [N] tensor, got {subset_mask.dtype} {tuple(subset_mask.shape)}")
    if render_rest_alone and (subset_mask is None or not render_depth):
        raise ValueError("render_rest_alone needs a subset_mask and render_depth=True")
    tensors = {"means": means, "quats": quats, "scales": scales, "opacities": opacities,
               "colors": colors, "viewmats": viewmats, "Ks": Ks}
    if backgrounds is not None:
        tensors["backgrounds"] = backgrounds
    for name, t in tensors.items():
        if t.dtype != means.dtype:
            raise ValueError(f"{name} has dtype {t.dtype}, expected {means.dtype} like means")
    bad = first_non_finite(tensors.items())
    if bad is not None:
        raise ValueError(f"{bad} contains NaN or Inf")
    if n > 0:
        if bool((torch.linalg.vector_norm(quats.detach(), dim=-1) == 0).any()):
            raise ValueError("quats contains a zero quaternion (no rotation defined)")
        if not log_scales and bool((scales.detach() <= 0).any()):
            raise ValueError("scales must be > 0 (pass log_scales=True for log-scales)")
        if bool(((opacities.detach() < 0) | (opacities.detach() > 1)).any()):
            raise ValueError("opacities must lie in [0, 1] (apply the sigmoid first)")


def _resolve_backend(backend: str, device: torch.device) -> str:
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "auto":
        if device.type == "cpu":
            return "cpu"
        return "gsplat" if device.type == "cuda" and gsplat_available() else "torch"
    if backend == "gsplat" and (device.type != "cuda" or not gsplat_available()):
        raise ValueError("backend='gsplat' needs CUDA tensors and the gsplat package")
    if backend == "cpu" and device.type != "cpu":
        raise ValueError(f"backend='cpu' needs CPU tensors, got {device}")
    return backend


def view_colors(colors: Tensor, means: Tensor, viewmats: Tensor, sh_degree: int | None,
                compiled: bool = False) -> Tensor:
    """Plain colours [N, D] unchanged, or SH evaluated per camera -> [C, N, D] (+0.5, clamped at 0).
    ``compiled``: the same maths in C++ (``cpu_backend.sh_colors``), except where the cameras
    need a gradient, which only the torch path gives."""
    if sh_degree is None:
        return colors
    rot = viewmats[:, :3, :3]
    campos = -torch.einsum("cji,cj->ci", rot, viewmats[:, :3, 3])
    if compiled and not viewmats.requires_grad:
        return sh_colors(colors, means, campos, sh_degree)
    dirs = means[None, :, :] - campos[:, None, :]
    return torch.clamp_min(eval_sh(sh_degree, colors[None], dirs) + 0.5, 0.0)


NEAR_PLANE = 0.01
"""Camera depth below which a Gaussian is not drawn, unless a call sets ``near_plane``."""


def rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    log_scales: bool = False,
    backgrounds: Tensor | None = None,
    near_plane: float = NEAR_PLANE,
    far_plane: float = 1e10,
    subset_mask: Tensor | None = None,
    render_depth: bool = True,
    normalize_depth: bool = False,
    render_rest_alone: bool = False,
    backend: str = "auto",
) -> RasterOutput:
    """Render N Gaussians into C cameras with 3DGS semantics, differentiably.

    Semantics: EWA projection with 0.3 px^2 dilation, 3-sigma square footprint, alpha clamped at
    0.99, contributions below 1/255 skipped, front-to-back by view z, and a pixel stops before the
    Gaussian that would take its transmittance below 1e-4. Cameras use OpenCV axes and pixel
    centres at +0.5. ``subset_alphas`` is the accumulated alpha of the masked Gaussians inside
    this same joint composite (their blending weights summed), not a separate render.
    ``render_rest_alone`` adds ``rest_depths`` and ``rest_alphas``: the depth (normalised as
    ``depths`` is) and alpha of the Gaussians outside ``subset_mask`` composited as if the subset
    were absent, i.e. what a separate render of them gives (the surface seen through no smoke).
    The cpu backend takes them from the same pass.
    """
    _validate(means, quats, scales, opacities, colors, viewmats, Ks, width, height, sh_degree,
              log_scales, backgrounds, near_plane, far_plane, subset_mask, render_depth, render_rest_alone)
    width, height = int(width), int(height)
    lin_scales = torch.exp(scales) if log_scales else scales
    chosen = _resolve_backend(backend, means.device)
    if chosen == "gsplat":
        from smokeseer.raster.gsplat_backend import rasterize_gsplat

        view_cols = view_colors(colors, means, viewmats, sh_degree)
        out = rasterize_gsplat(
            means, quats, lin_scales, opacities, view_cols, viewmats, Ks, width, height,
            backgrounds=backgrounds, near_plane=near_plane, far_plane=far_plane,
            subset_mask=subset_mask, render_depth=render_depth, normalize_depth=normalize_depth,
        )
        if not render_rest_alone:
            return out
        keep = ~subset_mask
        rest = rasterize_gsplat(
            means[keep], quats[keep], lin_scales[keep], opacities[keep], view_cols[..., keep, :1],
            viewmats, Ks, width, height, backgrounds=None, near_plane=near_plane, far_plane=far_plane,
            subset_mask=None, render_depth=True, normalize_depth=normalize_depth,
        )
        return replace(out, rest_depths=rest.depths, rest_alphas=rest.alphas)

    c = viewmats.shape[0]
    # The compiled projection has no gradient for Ks; differentiable intrinsics take the torch one
    # (same maths, so the outputs agree to rounding).
    project = project_compiled if chosen == "cpu" and not Ks.requires_grad else project_gaussians
    proj = project(means, quats, lin_scales, viewmats, Ks, width, height, near_plane, far_plane)
    if proj.means2d.requires_grad:
        proj.means2d.retain_grad()
    comp = (composite_tiles if chosen == "cpu" else composite)(
        proj, opacities, view_colors(colors, means, viewmats, sh_degree, compiled=chosen == "cpu"), width, height,
        render_depth=render_depth, subset_mask=subset_mask, rest_alone=render_rest_alone,
    )
    alphas = comp.alphas.reshape(c, height, width, 1)
    img = comp.colors.reshape(c, height, width, -1)
    if backgrounds is not None:
        bg = backgrounds.reshape(-1, 1, 1, img.shape[-1]) if backgrounds.dim() == 2 else backgrounds
        img = img + (1.0 - alphas) * bg
    depths = comp.depths.reshape(c, height, width, 1) if render_depth else None
    if render_depth and normalize_depth:
        depths = normalised_depth(depths, alphas)
    rest_depths = rest_alphas = None
    if render_rest_alone:
        rest_alphas = comp.rest_alphas.reshape(c, height, width, 1)
        rest_depths = comp.rest_depths.reshape(c, height, width, 1)
        if normalize_depth:
            rest_depths = normalised_depth(rest_depths, rest_alphas)
    subset = comp.subset_alphas.reshape(c, height, width, 1) if subset_mask is not None else None
    return RasterOutput(
        colors=img,
        alphas=alphas,
        depths=depths,
        subset_alphas=subset,
        means2d=proj.means2d,
        radii=proj.radii.clamp_max(RADIUS_INT_MAX).to(torch.int32),
        visible=proj.visible,
        n_pairs=comp.n_pairs,
        rest_depths=rest_depths,
        rest_alphas=rest_alphas,
    )
