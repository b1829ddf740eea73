"""The learned environment: geometry of its rays, SH values, compositing, gradients, and that a
trained run recovers a sky it was never told about."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from PIL import Image

from contracts.imageio import read_exr_channel
from smokeseer.cli import main
from smokeseer.model.background import EnvironmentBackground, ray_directions
from smokeseer.model.scene import Placed, View, render
from tests.test_smokeseer_data import write_splat_dataset
from tests.test_trainer import TINY


def _camera(seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    vm = np.eye(4)
    vm[:3, :3], vm[:3, 3] = q, rng.normal(size=3)
    k = np.array([[40.0, 0.0, 17.0], [0.0, 44.0, 11.5], [0.0, 0.0, 1.0]])
    return torch.tensor(vm), torch.tensor(k)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rays_project_back_to_their_pixel_centres(seed: int) -> None:
    vm, k = _camera(seed)
    w, h = 34, 23
    dirs = ray_directions(vm, k, w, h)
    centre = -vm[:3, :3].T @ vm[:3, 3]
    pts = centre + 2.5 * dirs / dirs.norm(dim=-1, keepdim=True)
    cam = pts @ vm[:3, :3].T + vm[:3, 3]
    assert bool((cam[..., 2] > 0).all())
    uv = (cam @ k.T)[..., :2] / cam[..., 2:3]
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64) + 0.5, torch.arange(w, dtype=torch.float64) + 0.5,
                          indexing="ij")
    assert torch.allclose(uv, torch.stack([u, v], dim=-1), atol=1e-9)


def test_view_keeps_the_sky_basis_and_gives_the_same_image() -> None:
    """A view renders its environment from a kept ray basis: same values and coefficient
    gradients as the uncached environment, computed once per SH degree; a camera whose pose
    requires grad is never kept (its gradient must flow)."""
    vm, k = _camera(4)
    env = EnvironmentBackground(3, degree=2, device=torch.device("cpu")).double()
    with torch.no_grad():
        env.coeffs.normal_(generator=torch.Generator().manual_seed(0))
    view = View(vm[None], k[None], 11, 8, 0.0)
    cached = view.sky(env)
    assert list(view.sky_bases) == [2]
    kept = view.sky_bases[2]
    assert torch.equal(cached, env(vm, k, 11, 8))
    grad_cached = torch.autograd.grad(view.sky(env).sum(), env.coeffs)[0]
    grad_direct = torch.autograd.grad(env(vm, k, 11, 8).sum(), env.coeffs)[0]
    assert view.sky_bases[2] is kept and torch.equal(grad_cached, grad_direct)
    posed = View(vm[None].clone().requires_grad_(True), k[None], 11, 8, 0.0)
    posed.sky(env).sum().backward()
    assert not posed.sky_bases and posed.viewmat.grad is not None


def test_sh_values_are_the_analytic_bands() -> None:
    vm, k = _camera(3)
    env = EnvironmentBackground(2, degree=1, device=torch.device("cpu")).double()
    with torch.no_grad():
        env.coeffs.zero_()
        env.coeffs[0, 0] = 0.4
        env.coeffs[2, 1] = 0.3
    img = env(vm, k, 9, 7)
    d = ray_directions(vm, k, 9, 7)
    z = d[..., 2] / d.norm(dim=-1)
    c0, c1 = 0.5 / math.sqrt(math.pi), math.sqrt(3.0 / (4.0 * math.pi))
    assert torch.allclose(img[..., 0], torch.full_like(z, 0.5 + c0 * 0.4), atol=1e-12)
    assert torch.allclose(img[..., 1], 0.5 + c1 * 0.3 * z, atol=1e-12)
    with pytest.raises(ValueError, match="background_sh_degree"):
        EnvironmentBackground(3, degree=4, device=torch.device("cpu"))


def _one_blob() -> tuple[Placed, torch.Tensor, torch.Tensor, View]:
    placed = Placed(torch.tensor([[0.1, -0.05, 3.0]], dtype=torch.float64),
                    torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64),
                    torch.log(torch.tensor([[0.4, 0.3, 0.2]], dtype=torch.float64)))
    k = torch.tensor([[[30.0, 0.0, 12.0], [0.0, 30.0, 9.0], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    view = View(torch.eye(4, dtype=torch.float64)[None], k, 24, 18, 0.0)
    return placed, torch.tensor([0.7], dtype=torch.float64), torch.tensor([[0.9, 0.2, 0.4]], dtype=torch.float64), view


def test_constant_environment_matches_the_rasterizers_own_background() -> None:
    placed, opac, col, view = _one_blob()
    sky = torch.tensor([0.3, 0.6, 0.8], dtype=torch.float64)
    env = EnvironmentBackground(3, degree=2, device=torch.device("cpu")).double()
    with torch.no_grad():
        env.coeffs.zero_()
        env.coeffs[0] = (sky - 0.5) * 2.0 * math.sqrt(math.pi)
    ours = render(view, [(placed, opac, col)], None, env)
    ref = render(view, [(placed, opac, col)], None, sky)
    assert torch.allclose(ours.colors, ref.colors, atol=1e-12)
    assert torch.allclose(ours.alphas, ref.alphas)


def test_environment_gradients_match_finite_differences() -> None:
    placed, opac, col, view = _one_blob()
    env = EnvironmentBackground(3, degree=2, device=torch.device("cpu")).double()
    with torch.no_grad():
        noise = torch.randn(env.coeffs.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
        env.coeffs.copy_(noise * 0.1)
    target = torch.rand(1, 18, 24, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def loss() -> torch.Tensor:
        return ((render(view, [(placed, opac, col)], None, env).colors - target) ** 2).sum()

    loss().backward()
    grad = env.coeffs.grad.clone()
    eps = 1e-6
    for idx in [(0, 0), (3, 1), (8, 2), (5, 0)]:
        with torch.no_grad():
            env.coeffs[idx] += eps
            up = float(loss())
            env.coeffs[idx] -= 2 * eps
            down = float(loss())
            env.coeffs[idx] += eps
        assert grad[idx].item() == pytest.approx((up - down) / (2 * eps), rel=1e-6, abs=1e-8)


@pytest.mark.parametrize("background", ["environment", "black"])
def test_surface_renders_recover_the_sky_only_with_an_environment(tmp_path: Path, background: str) -> None:
    ds = write_splat_dataset(tmp_path / "sky", n_rgb=8, n_thermal=6, sky=(0.55, 0.7, 0.9))
    run = tmp_path / background
    budget = ["--iterations-stage3", "120", "--set", f"background={background}"]
    assert main([str(ds), "--out", str(run)] + TINY + budget) == 0
    errors = []
    for png in sorted((run / "renders" / "surface").glob("*.png")):
        pred = np.asarray(Image.open(png), dtype=np.float64) / 255.0
        clean = np.asarray(Image.open(ds / "rgb" / "clean" / png.name), dtype=np.float64) / 255.0
        sky = read_exr_channel(ds / "rgb" / "depth" / f"{png.stem}.exr", "Z") == 0
        errors.append(np.abs(pred - clean)[sky].mean())
    assert errors
    if background == "environment":
        assert max(errors) < 0.06, errors
    else:
        assert min(errors) > 0.5, errors
