"""Losses, deformation and temporal opacity against independent references and analytic cases."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from contracts.metrics import ssim_3dgs
from smokeseer.config import DeformConfig
from smokeseer.model.deform import DeformNetwork, positional_encoding, temporal_opacity
from smokeseer.train.losses import (align_scale_shift, depth_consistency, mask_alignment, monochromaticity,
                                    render_loss, smoke_alpha_variance, smoke_color_variance, ssim)


def test_torch_ssim_matches_eval_metrics_numpy_implementation() -> None:
    rng = np.random.default_rng(0)
    a = rng.random((30, 41, 3))
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    ours = float(ssim(torch.tensor(a), torch.tensor(b)))
    assert ours == pytest.approx(ssim_3dgs(a, b), abs=1e-9)
    assert float(ssim(torch.tensor(a), torch.tensor(a))) == pytest.approx(1.0, abs=1e-12)


def test_render_loss_gradient_matches_finite_differences() -> None:
    torch.manual_seed(0)
    x = torch.rand(6, 7, 2, dtype=torch.float64, requires_grad=True)
    y = torch.rand(6, 7, 2, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p: render_loss(p, y), (x,), eps=1e-6, atol=1e-5, fast_mode=True)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.05, 20.0), st.floats(-5.0, 5.0), st.integers(0, 1000))
def test_scale_shift_alignment_recovers_known_affine(s: float, b: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    prior = torch.tensor(rng.uniform(0.5, 4.0, (10, 12)))
    depth = s * prior + b
    valid = torch.tensor(rng.random((10, 12)) > 0.3)
    es, eb = align_scale_shift(depth, prior, valid)
    assert float(es) == pytest.approx(s, rel=1e-6, abs=1e-9)
    assert float(eb) == pytest.approx(b, abs=1e-6 * max(1.0, abs(b)))
    assert float(depth_consistency(depth, prior, valid)) == pytest.approx(0.0, abs=1e-8)


def test_depth_term_is_the_mean_residual_after_alignment() -> None:
    """Depth term against a hand sum: the L1 residual to the scale/shift-aligned prior, averaged
    over the valid pixels only."""
    rng = np.random.default_rng(5)
    prior = torch.tensor(rng.uniform(1.0, 4.0, (6, 7)))
    depth = 0.5 * prior + 0.3 + torch.tensor(rng.normal(0.0, 0.2, (6, 7)))
    valid = torch.tensor(rng.random((6, 7)) > 0.2)
    s, b = align_scale_shift(depth, prior, valid)
    by_hand = float((depth - (s * prior + b)).abs()[valid].sum() / valid.sum())
    assert float(depth_consistency(depth, prior, valid)) == pytest.approx(by_hand, rel=1e-12)


def test_alignment_is_stable_on_constant_prior_and_empty_mask() -> None:
    depth = torch.full((4, 4), 2.0, requires_grad=True)
    prior = torch.ones(4, 4)
    loss = depth_consistency(depth, prior, torch.ones(4, 4, dtype=torch.bool))
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(depth.grad).all()
    assert float(depth_consistency(depth, prior, torch.zeros(4, 4, dtype=torch.bool)).detach()) == 0.0


def test_smoke_priors_analytic_values() -> None:
    colors = torch.tensor([[0.2, 0.2, 0.2], [0.4, 0.4, 0.4]])
    assert float(monochromaticity(colors)) == pytest.approx(0.0)
    assert float(smoke_color_variance(colors)) == pytest.approx(0.01)
    tinted = torch.tensor([[0.0, 0.5, 1.0]])
    assert float(monochromaticity(tinted)) == pytest.approx(np.var([0.0, 0.5, 1.0]))
    assert float(smoke_alpha_variance(torch.tensor([0.1, 0.3]))) == pytest.approx(0.01)
    assert float(smoke_alpha_variance(torch.tensor([0.7]))) == 0.0
    assert float(mask_alignment(torch.tensor([0.2, 1.0]), torch.tensor([0.0, 1.0]), floor=0.4)) == pytest.approx(0.1)
    # Inside the mask, alpha at or above the floor is enough; below it, the gap to 1 counts.
    a = torch.tensor([0.5, 0.1, 0.3], requires_grad=True)
    loss = mask_alignment(a, torch.tensor([1.0, 1.0, 0.0]), floor=0.4)
    assert float(loss.detach()) == pytest.approx((0.0 + 0.9 + 0.3) / 3)
    loss.backward()
    assert a.grad.tolist() == pytest.approx([0.0, -1 / 3, 1 / 3])
    assert float(mask_alignment(torch.tensor([0.5]), torch.tensor([1.0]), floor=1.0)) == pytest.approx(0.5)


def test_temporal_opacity_is_bimodal_plateau_with_gaussian_falloff() -> None:
    lo, hi, ls = torch.tensor([0.3]), torch.tensor([0.6]), torch.tensor([math.log(0.1)])
    for t in (0.3, 0.45, 0.6):
        assert float(temporal_opacity(t, lo, hi, ls)) == pytest.approx(1.0)
    assert float(temporal_opacity(0.1, lo, hi, ls)) == pytest.approx(math.exp(-0.5 * (0.2 / 0.1) ** 2))
    assert float(temporal_opacity(0.8, lo, hi, ls)) == pytest.approx(math.exp(-0.5 * (0.2 / 0.1) ** 2))
    # Swapped centres mean the same interval.
    assert float(temporal_opacity(0.45, hi, lo, ls)) == pytest.approx(1.0)


def test_temporal_opacity_gradients_finite_at_extremes() -> None:
    lo = torch.tensor([0.5, -50.0, 0.2], requires_grad=True)
    hi = torch.tensor([0.5, 50.0, 0.2], requires_grad=True)
    ls = torch.tensor([-30.0, 30.0, 0.0], requires_grad=True)
    out = temporal_opacity(0.9, lo, hi, ls)
    out.sum().backward()
    for t in (out, lo.grad, hi.grad, ls.grad):
        assert torch.isfinite(t).all()


def test_positional_encoding_layout() -> None:
    x = torch.tensor([[0.25]])
    enc = positional_encoding(x, 2)
    expected = [0.25, math.sin(math.pi * 0.25), math.sin(2 * math.pi * 0.25),
                math.cos(math.pi * 0.25), math.cos(2 * math.pi * 0.25)]
    np.testing.assert_allclose(enc[0].numpy(), expected, atol=1e-7)


def test_deform_network_defaults_and_zero_start() -> None:
    cfg = DeformConfig()
    assert (cfg.depth, cfg.width, cfg.skip_layer, cfg.xyz_frequencies, cfg.t_frequencies) == (8, 256, 4, 10, 6)
    net = DeformNetwork(cfg, position_scale=2.0, device=torch.device("cpu"))
    assert net.layers[cfg.skip_layer].in_features == cfg.width + 63 + 13
    means = torch.randn(5, 3)
    d_xyz, d_rot, d_scale = net(means, 0.3, torch.zeros(3))
    assert torch.equal(d_xyz, torch.zeros(5, 3)) and d_rot is None and d_scale is None
    full = DeformNetwork(DeformConfig(depth=3, width=16, skip_layer=1, predict_rotation_scale=True), 1.0, torch.device("cpu"))
    _, d_rot, d_scale = full(means, 0.3, torch.zeros(3))
    assert d_rot.shape == (5, 4) and d_scale.shape == (5, 3)


def test_deformation_sees_detached_canonical_positions() -> None:
    """Deformable 3DGS feeds the MLP detached positions: the canonical means get gradient only
    through the offset they receive (d loss / d means = 1 for loss = sum of deformed means)."""
    from smokeseer.model.scene import place_deformed
    from smokeseer.model.gaussians import GaussianSet

    torch.manual_seed(0)
    net = DeformNetwork(DeformConfig(depth=3, width=16, skip_layer=1), 1.0, torch.device("cpu"))
    torch.nn.init.normal_(net.head.weight, std=0.5)
    n = 6
    g = GaussianSet({"means": torch.randn(n, 3), "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                     "log_scales": torch.zeros(n, 3)})
    placed = place_deformed(g, net, 0.4, torch.zeros(3), active=True)
    assert not torch.allclose(placed.means, g["means"])
    placed.means.sum().backward()
    assert torch.equal(g["means"].grad, torch.ones(n, 3))
    assert net.head.weight.grad is not None and net.head.weight.grad.abs().sum() > 0


def _ssim_dense_reference(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The former implementation: one 11×11 grouped convolution per map, zero padding."""
    c = pred.shape[-1]
    x, y = pred.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None]
    t = torch.arange(11, dtype=pred.dtype) - 5
    g = torch.exp(-(t ** 2) / (2 * 1.5 ** 2))
    g = g / g.sum()
    w = torch.outer(g, g).expand(c, 1, 11, 11).contiguous()

    def blur(z: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.conv2d(z, w, padding=5, groups=c)

    mx, my = blur(x), blur(y)
    sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    num = (2 * mx * my + 0.01 ** 2) * (2 * sxy + 0.03 ** 2)
    den = (mx * mx + my * my + 0.01 ** 2) * (sxx + syy + 0.03 ** 2)
    return (num / den).mean()


@pytest.mark.parametrize("shape", [(30, 41, 3), (7, 5, 1), (64, 48, 2)])
def test_separable_ssim_equals_dense_11x11_value_and_gradient(shape: tuple[int, int, int]) -> None:
    gen = torch.Generator().manual_seed(sum(shape))
    a = torch.rand(shape, generator=gen, dtype=torch.float32, requires_grad=True)
    b = (a.detach() + 0.1 * torch.randn(shape, generator=gen)).clamp(0, 1)
    ours = ssim(a, b)
    (g_ours,) = torch.autograd.grad(ours, a)
    ref = _ssim_dense_reference(a, b)
    (g_ref,) = torch.autograd.grad(ref, a)
    assert abs(float(ours.detach()) - float(ref.detach())) < 1e-6
    assert float((g_ours - g_ref).abs().max()) < 1e-6 * max(1.0, float(g_ref.abs().max()))
