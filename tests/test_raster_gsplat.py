"""Parity of the torch backend with gsplat.rasterization on CUDA (skipped without CUDA + gsplat).

Scenes keep opacity below 0.3 so the two libraries' different cut-offs cannot matter: gsplat
clamps alpha at 0.999 (we use 0.99) and evaluates whole 16x16 tiles (we use the 3-sigma square),
but beyond 3 sigma alpha = opacity * exp(-4.5) < 1/255 for opacity < 0.35, and no pixel nears 0.99.
"""

from __future__ import annotations

import pytest
import torch

from smokeseer.raster import gsplat_available, rasterize
from tests.test_raster import random_scene

pytestmark = [
    pytest.mark.cuda,
    pytest.mark.skipif(not (torch.cuda.is_available() and gsplat_available()), reason="needs CUDA and gsplat"),
]


@pytest.mark.parametrize("sh_degree", [None, 3])
def test_outputs_and_gradients_match_gsplat(sh_degree: int | None) -> None:
    dev = torch.device("cuda")
    scene = random_scene(21, 3000, c=2, width=96, height=64, dtype=torch.float32, scale=(0.005, 0.08))
    means, quats, scales, opac, colors, vm, ks, w, h = scene
    opac = 0.02 + 0.27 * opac
    if sh_degree is not None:
        colors = torch.randn(means.shape[0], 16, 3, generator=torch.Generator().manual_seed(3)) * 0.2
    mask = torch.arange(means.shape[0]) % 4 == 0
    weights = torch.randn(2, h, w, 6, device=dev)
    results = {}
    for backend in ("torch", "gsplat"):
        params = [t.to(dev).clone().requires_grad_(True) for t in (means, quats, scales, opac, colors)]
        out = rasterize(*params, vm.to(dev), ks.to(dev), w, h, sh_degree=sh_degree, backend=backend,
                        subset_mask=mask.to(dev), backgrounds=torch.tensor([0.1, 0.2, 0.3], device=dev))
        stacked = torch.cat([out.colors, out.alphas, out.depths, out.subset_alphas], dim=-1)
        (stacked * weights).sum().backward()
        results[backend] = (stacked.detach(), [p.grad for p in params], out.means2d.grad, out.visible)
    img_t, grads_t, m2g_t, vis_t = results["torch"]
    img_g, grads_g, m2g_g, vis_g = results["gsplat"]
    assert float(img_t[..., 3].max()) > 0.5
    torch.testing.assert_close(img_t, img_g, atol=2e-4, rtol=1e-3)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colors"), grads_t, grads_g):
        scale = float(b.abs().max())
        assert float((a - b).abs().max()) <= 2e-3 * scale + 1e-5, name
    both = vis_t & vis_g
    scale = float(m2g_g[both].abs().max())
    assert float((m2g_t[both] - m2g_g[both]).abs().max()) <= 2e-3 * scale + 1e-6


def test_rest_alone_matches_the_torch_backend_on_gsplat() -> None:
    dev = torch.device("cuda")
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(22, 2000, c=2, width=96, height=64,
                                                                    dtype=torch.float32, scale=(0.005, 0.08))
    opac = 0.02 + 0.27 * opac
    mask = torch.arange(means.shape[0]) % 3 == 0
    weights = torch.randn(2, h, w, 2, device=dev)
    results = {}
    for backend in ("torch", "gsplat"):
        params = [t.to(dev).clone().requires_grad_(True) for t in (means, quats, scales, opac)]
        out = rasterize(*params, colors.to(dev), vm.to(dev), ks.to(dev), w, h, backend=backend,
                        subset_mask=mask.to(dev), normalize_depth=True, render_rest_alone=True)
        stacked = torch.cat([out.rest_depths, out.rest_alphas], dim=-1)
        (stacked * weights).sum().backward()
        results[backend] = (stacked.detach(), [p.grad for p in params])
    (img_t, grads_t), (img_g, grads_g) = results["torch"], results["gsplat"]
    assert float(img_t[..., 1].max()) > 0.5
    torch.testing.assert_close(img_t, img_g, atol=2e-4, rtol=1e-3)
    for name, a, b in zip(("means", "quats", "scales", "opacities"), grads_t, grads_g):
        assert float((a - b).abs().max()) <= 2e-3 * float(b.abs().max()) + 1e-5, name
