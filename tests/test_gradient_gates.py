"""Gradient gates that leave a render's image unchanged.

- stage3.thermal_surface_grad=smoky-views: the gradient the thermal render sends into each surface
  Gaussian's position, shape and opacity is that Gaussian's share times the ungated one (checked
  against the ungated render's own gradient), while its thermal value learns in full.
- background_from=clear-pixels: the environment's gradient is each pixel's weight times what that
  pixel sends it (checked against the chain rule written out through the composite)."""
from __future__ import annotations

import numpy as np
import torch

from smokeseer.config import make_config
from smokeseer.model.background import EnvironmentBackground
from smokeseer.model.gaussians import GaussianSet
from smokeseer.model.scene import SceneModel, add_rgb_sh, init_gaussians, make_smoke, make_view, scaled_gradient

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


K = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])


def _view():
    return make_view(np.eye(4), K, 64, 48, 0.0, torch.device("cpu"))


def _grads(share: torch.Tensor | None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    surface = _surface()
    model = SceneModel(surface, None, None, True, torch.zeros(3), 0)
    image = model.render_thermal(_view(), depth=False, surface_grad_share=share).colors[0]
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


def test_the_environment_learns_each_pixel_by_its_weight() -> None:
    """A weight per pixel (1 − a smoke mask): the image is the ungated one, and the environment's
    gradient equals the chain rule through C = colour + (1 − alpha) × sky with each pixel's
    upstream gradient times its weight; all-ones weights give the ungated gradient exactly."""
    surface = _surface()
    tensors = surface.state_dict()
    add_rgb_sh(tensors, 0)
    surface = GaussianSet(tensors)
    env = EnvironmentBackground(3, 2, torch.device("cpu"))
    env.coeffs.data = torch.as_tensor(np.random.default_rng(5).normal(0, 0.3, env.coeffs.shape), dtype=torch.float32)
    model = SceneModel(surface, None, None, True, torch.zeros(3), 0, background_rgb=env)
    view = _view()
    weights = torch.ones(48, 64)
    weights[:, :20] = 0.0       # a smoke mask over the left third
    weights[30:, 40:] = 0.25    # a soft one in a corner
    target = torch.linspace(-1.0, 1.0, 48 * 64 * 3).reshape(48, 64, 3)

    def env_grad(w: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        env.coeffs.grad = None
        out = model.render_rgb(view, degree=0, depth=False, background_grad=w)
        (out.colors[0] * target).sum().backward()
        return out.colors[0].detach(), out.alphas[0, ..., 0].detach(), env.coeffs.grad.clone()

    plain_image, alpha, plain = env_grad(None)
    image, _, gated = env_grad(weights)
    torch.testing.assert_close(image, plain_image, rtol=0, atol=0)
    env.coeffs.grad = None
    (view.sky(env) * ((1.0 - alpha)[..., None] * target * weights[..., None])).sum().backward()
    torch.testing.assert_close(gated, env.coeffs.grad, rtol=1e-4, atol=1e-6)
    assert not torch.allclose(gated, plain)
    torch.testing.assert_close(env_grad(torch.ones(48, 64))[2], plain, rtol=0, atol=0)


def test_only_an_rgb_stage2_learning_from_clear_pixels_has_its_own_key() -> None:
    """background_from=clear-pixels makes an RGB Stage 2 read Stage 1's masks, so its checkpoint
    key takes the option and where the masks come from; the thermal Stage 2 is Full's."""
    def key(mode: str, **overrides: object) -> str:
        return make_config(mode, "standard", 0, dict(overrides)).stage2_sha256()

    assert key("full", background_from="clear-pixels") == key("full")
    assert key("full", background_from="clear-pixels", stage1="estimate") == key("full")
    assert key("rgb-only", background_from="clear-pixels") != key("rgb-only")
    assert (key("rgb-only", background_from="clear-pixels", stage1="estimate")
            != key("rgb-only", background_from="clear-pixels"))
    assert key("rgb-only", stage1="estimate") == key("rgb-only")
