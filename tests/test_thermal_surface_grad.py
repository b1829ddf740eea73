"""stage3.thermal_surface_grad=smoky-views: the thermal render is unchanged, and the gradient it
sends into each surface Gaussian's position, shape and opacity is that Gaussian's share times the
ungated one (checked against the ungated render's own gradient), while its thermal value learns
in full."""
from __future__ import annotations

import numpy as np
import torch

from smokeseer.model.gaussians import GaussianSet
from smokeseer.model.scene import SceneModel, init_gaussians, make_view, scaled_gradient

GEOMETRY = ("means", "quats", "log_scales", "opacity")


def test_scaled_gradient_keeps_the_value_and_scales_each_rows_gradient() -> None:
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(6, 3, generator=gen, requires_grad=True)
    share = torch.tensor([0.0, 0.25, 0.5, 0.75, 1.0, 0.1])
    weights = torch.randn(6, 3, generator=gen)
    y = scaled_gradient(x, share)
    torch.testing.assert_close(y, x, rtol=0, atol=0)
    (y * weights).sum().backward()
    torch.testing.assert_close(x.grad, share[:, None] * weights, rtol=0, atol=1e-7)


def _surface() -> GaussianSet:
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-0.8, 0.8, 30), rng.uniform(-0.6, 0.6, 30), rng.uniform(2.5, 3.5, 30)])
    tensors = init_gaussians(points, 0.6, 0.3, torch.device("cpu"))
    tensors["thermal"] = torch.as_tensor(rng.normal(0, 1, (30, 1)), dtype=torch.float32)
    return GaussianSet(tensors)


def _grads(share: torch.Tensor | None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    surface = _surface()
    model = SceneModel(surface, None, None, True, torch.zeros(3), 0)
    K = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])
    view = make_view(np.eye(4), K, 64, 48, 0.0, torch.device("cpu"))
    image = model.render_thermal(view, depth=False, surface_grad_share=share).colors[0]
    target = torch.linspace(0.0, 1.0, image.numel()).reshape(image.shape)
    ((image - target) ** 2).sum().backward()
    return image.detach(), {k: surface.params[k].grad.clone() for k in (*GEOMETRY, "thermal")}


def test_the_gated_thermal_render_scales_the_geometry_gradient_by_each_share() -> None:
    share = torch.as_tensor(np.random.default_rng(4).uniform(0, 1, 30), dtype=torch.float32)
    share[:5] = 0.0
    share[5:10] = 1.0
    plain_image, plain = _grads(None)
    image, gated = _grads(share)
    torch.testing.assert_close(image, plain_image, rtol=0, atol=0)
    assert torch.count_nonzero(plain["means"]) > 0
    for key in GEOMETRY:
        expected = share.reshape(-1, *([1] * (plain[key].dim() - 1))) * plain[key]
        torch.testing.assert_close(gated[key], expected, rtol=1e-5, atol=1e-9)
    torch.testing.assert_close(gated["thermal"], plain["thermal"], rtol=0, atol=0)
