"""Parity of gsplat.rasterization (CUDA) with our backends: the compiled CPU kernel on CPU tensors
and the torch backend on the same GPU. Skipped without CUDA and gsplat; the GPU check
(scripts/gpu_check.sh) runs this file on the GPU node and records each test's printed errors.

Where the two agree by construction, the scenes keep opacity below 0.3: gsplat clamps alpha at
0.999 where we clamp at 0.99, and it blends every pixel of its tiles where alpha reaches 1/255
(an opacity-aware ellipse of sqrt(2 ln(255 o)) sigma) where we stop at the 3-sigma square; below
opacity 0.35 that ellipse lies inside 3 sigma, and no pixel's alpha nears 0.99. The dilation
(0.3 px^2, no compensation) and the early stop (before the Gaussian that takes T to 1e-4) are the
same in both. The last two tests measure the two differences where they do show.

Tolerances (float32 both sides; gsplat uses fast-math exponentials): images 2e-4 absolute plus
1e-3 relative; gradients of means, quaternions, scales, opacities, colours and means2d within
2e-3 of the largest entry of gsplat's.
"""
from __future__ import annotations

import pytest
import torch
from torch import Tensor

from smokeseer.raster import gsplat_available, rasterize
from tests.raster_reference import random_scene

pytestmark = [
    pytest.mark.cuda,
    pytest.mark.skipif(not (torch.cuda.is_available() and gsplat_available()), reason="needs CUDA and gsplat"),
]
IMAGE_ATOL, IMAGE_RTOL, GRAD_REL = 2e-4, 1e-3, 2e-3


def _device(backend: str) -> torch.device:
    return torch.device("cpu" if backend == "cpu" else "cuda")


def _gradient_gap(name: str, ours: Tensor, theirs: Tensor, floor: float = 1e-5) -> None:
    scale = float(theirs.abs().max())
    gap = float((ours - theirs).abs().max())
    print(f"{name}: max |grad difference| {gap:.3g}, largest gsplat entry {scale:.3g}")
    assert gap <= GRAD_REL * scale + floor, name


@pytest.mark.parametrize("reference", ["cpu", "torch"])
@pytest.mark.parametrize("sh_degree", [None, 3])
def test_outputs_and_gradients_match_gsplat(reference: str, sh_degree: int | None) -> None:
    scene = random_scene(21, 3000, c=2, width=96, height=64, dtype=torch.float32, scale=(0.005, 0.08))
    means, quats, scales, opac, colors, vm, ks, w, h = scene
    opac = 0.02 + 0.27 * opac
    if sh_degree is not None:
        colors = torch.randn(means.shape[0], 16, 3, generator=torch.Generator().manual_seed(3)) * 0.2
    mask = torch.arange(means.shape[0]) % 4 == 0
    weights = torch.randn(2, h, w, 6, generator=torch.Generator().manual_seed(4))
    results = {}
    for backend in (reference, "gsplat"):
        dev = _device(backend)
        params = [t.to(dev).clone().requires_grad_(True) for t in (means, quats, scales, opac, colors)]
        out = rasterize(*params, vm.to(dev), ks.to(dev), w, h, sh_degree=sh_degree, backend=backend,
                        subset_mask=mask.to(dev), backgrounds=torch.tensor([0.1, 0.2, 0.3], device=dev))
        stacked = torch.cat([out.colors, out.alphas, out.depths, out.subset_alphas], dim=-1)
        (stacked * weights.to(dev)).sum().backward()
        results[backend] = (stacked.detach().cpu(), [p.grad.cpu() for p in params], out.means2d.grad.cpu(),
                            out.visible.cpu(), out.radii.cpu())
    img_r, grads_r, m2g_r, vis_r, radii_r = results[reference]
    img_g, grads_g, m2g_g, vis_g, radii_g = results["gsplat"]
    # Densification reads radii and visibility: the same Gaussians, the same pixel radii.
    assert torch.equal(vis_r, vis_g) and torch.equal(radii_r, radii_g)
    assert float(img_r[..., 3].max()) > 0.5
    for i, name in enumerate(("red", "green", "blue", "alpha", "depth", "subset alpha")):
        print(f"{name}: max |difference| {float((img_r[..., i] - img_g[..., i]).abs().max()):.3g}")
    torch.testing.assert_close(img_r, img_g, atol=IMAGE_ATOL, rtol=IMAGE_RTOL)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colors"), grads_r, grads_g):
        _gradient_gap(name, a, b)
    both = vis_r & vis_g
    _gradient_gap("means2d", m2g_r[both], m2g_g[both], floor=1e-6)


@pytest.mark.parametrize("reference", ["cpu", "torch"])
def test_rest_alone_matches_gsplat(reference: str) -> None:
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(22, 2000, c=2, width=96, height=64,
                                                                    dtype=torch.float32, scale=(0.005, 0.08))
    opac = 0.02 + 0.27 * opac
    mask = torch.arange(means.shape[0]) % 3 == 0
    weights = torch.randn(2, h, w, 2, generator=torch.Generator().manual_seed(5))
    results = {}
    for backend in (reference, "gsplat"):
        dev = _device(backend)
        params = [t.to(dev).clone().requires_grad_(True) for t in (means, quats, scales, opac)]
        out = rasterize(*params, colors.to(dev), vm.to(dev), ks.to(dev), w, h, backend=backend,
                        subset_mask=mask.to(dev), normalize_depth=True, render_rest_alone=True)
        stacked = torch.cat([out.rest_depths, out.rest_alphas], dim=-1)
        (stacked * weights.to(dev)).sum().backward()
        results[backend] = (stacked.detach().cpu(), [p.grad.cpu() for p in params])
    (img_r, grads_r), (img_g, grads_g) = results[reference], results["gsplat"]
    assert float(img_r[..., 1].max()) > 0.5
    print(f"rest depth, alpha: max |difference| {float((img_r - img_g).abs().max()):.3g}")
    torch.testing.assert_close(img_r, img_g, atol=IMAGE_ATOL, rtol=IMAGE_RTOL)
    for name, a, b in zip(("means", "quats", "scales", "opacities"), grads_r, grads_g):
        _gradient_gap(name, a, b)


def _one_gaussian(opacity: float, backend: str, size: int = 81) -> Tensor:
    """The alpha image of one isotropic Gaussian of 10 px standard deviation on screen (with the
    0.3 px^2 dilation), centred on a pixel centre of a square image. Our footprint is then the
    square of half-width ceil(3 * sqrt(100 + 0.1)) = 31 px; gsplat's reaches 3.30 * 10 = 33 px at
    opacity 0.9."""
    dev = _device(backend)
    focal = 100.0
    view = torch.eye(4, device=dev)
    view[2, 3] = 5.0
    k = torch.tensor([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1]], device=dev)
    out = rasterize(torch.zeros(1, 3, device=dev), torch.tensor([[1.0, 0, 0, 0]], device=dev),
                    torch.full((1, 3), (100.0 - 0.3) ** 0.5 * 5.0 / focal, device=dev), torch.tensor([opacity], device=dev),
                    torch.ones(1, 3, device=dev), view[None], k[None], size, size, backend=backend)
    return out.alphas[0, ..., 0].cpu()


def test_alpha_clamp_is_the_one_difference_at_an_opaque_centre() -> None:
    """An opaque Gaussian's centre: 0.99 here, 0.999 in gsplat (3DGS uses 0.99)."""
    ours, theirs = _one_gaussian(1.0, "cpu"), _one_gaussian(1.0, "gsplat")
    print(f"peak alpha: ours {float(ours.max()):.6f}, gsplat {float(theirs.max()):.6f}")
    assert float(ours.max()) == pytest.approx(0.99, abs=1e-6)
    assert float(theirs.max()) == pytest.approx(0.999, abs=1e-6)
    # Away from the clamp the two agree, inside the footprint both blend (at opacity 1 gsplat's
    # reaches sqrt(2 ln 255) = 3.33 sigma: the ring of the next test).
    below = (ours > 0) & (theirs > 0) & (ours < 0.985) & (theirs < 0.985)
    torch.testing.assert_close(ours[below], theirs[below], atol=IMAGE_ATOL, rtol=IMAGE_RTOL)


def test_footprint_difference_is_a_faint_ring_beyond_three_sigma() -> None:
    """At opacity 0.9, gsplat blends out to sqrt(2 ln(255 * 0.9)) = 3.30 sigma, we to the 3-sigma
    square: the pixels only gsplat blends (32-33 px from the centre) hold alpha below
    0.9 * exp(-4.5) = 0.01."""
    ours, theirs = _one_gaussian(0.9, "cpu"), _one_gaussian(0.9, "gsplat")
    only_theirs = (ours == 0) & (theirs > 0)
    print(f"pixels only gsplat blends: {int(only_theirs.sum())}, their largest alpha "
          f"{float(theirs[only_theirs].max()) if only_theirs.any() else 0.0:.4f}")
    assert bool(only_theirs.any())
    assert float(theirs[only_theirs].max()) <= 0.9 * float(torch.exp(torch.tensor(-4.5))) + 1e-4
    assert not bool(((ours > 0) & (theirs == 0)).any())
    both = (ours > 0) & (theirs > 0)
    torch.testing.assert_close(ours[both], theirs[both], atol=IMAGE_ATOL, rtol=IMAGE_RTOL)
