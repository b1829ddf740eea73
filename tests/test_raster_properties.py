"""Property tests: extreme but valid inputs give finite outputs and finite gradients."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from smokeseer.raster import rasterize
from tests.raster_reference import dense_rasterize, every_cpu_backend  # noqa: F401 (fixture)

pytestmark = pytest.mark.usefixtures("every_cpu_backend")

W, H = 12, 10

finite = st.floats(allow_nan=False, allow_infinity=False)


@st.composite
def extreme_scenes(draw):
    """Small scenes mixing the regimes that break naive rasterizers."""
    n = draw(st.integers(0, 6))
    dtype = draw(st.sampled_from([torch.float32, torch.float64]))
    means, quats, log_scales, logits = [], [], [], []
    for _ in range(n):
        kind = draw(st.sampled_from(["normal", "behind", "near_plane", "off_screen", "huge_xy"]))
        x, y = draw(finite.filter(lambda v: -2 <= v <= 2)), draw(finite.filter(lambda v: -2 <= v <= 2))
        z = {"normal": draw(st.floats(0.05, 50)), "behind": draw(st.floats(-50, 0.0)),
             "near_plane": 0.01, "off_screen": draw(st.floats(0.05, 5)), "huge_xy": draw(st.floats(0.011, 0.05))}[kind]
        if kind in ("off_screen", "huge_xy"):
            x, y = x * 1e4, y * 1e4
        means.append([x, y, z])
        # Un-normalised quaternions over 6 orders of magnitude, never exactly zero.
        q = [draw(st.floats(-1, 1)) for _ in range(4)]
        q[0] = q[0] if abs(q[0]) > 1e-3 else 1.0
        mag = 10.0 ** draw(st.floats(-3, 3))
        quats.append([mag * v for v in q])
        shape = draw(st.sampled_from(["any", "needle", "flat", "tiny", "huge"]))
        ls = [draw(st.floats(math.log(1e-6), math.log(1e3))) for _ in range(3)]
        if shape == "needle":
            ls = [math.log(1e3), math.log(1e-6), math.log(1e-6)]
        elif shape == "flat":
            ls = [math.log(1.0), math.log(1.0), math.log(1e-6)]
        elif shape == "tiny":
            ls = [math.log(1e-6)] * 3
        elif shape == "huge":
            ls = [math.log(1e3)] * 3
        log_scales.append(ls)
        logits.append(draw(st.sampled_from([-50.0, 50.0, 0.0])) + draw(st.floats(-1, 1)))
    t = lambda v, shape: torch.tensor(v, dtype=dtype).reshape(shape)  # noqa: E731
    return (t(means, (n, 3)), t(quats, (n, 4)), t(log_scales, (n, 3)), t(logits, (n,)),
            draw(st.integers(0, 3)) if n else 0, dtype, draw(st.sampled_from([15.0, 2000.0, 1e5])))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(extreme_scenes(), st.booleans())
def test_extreme_inputs_are_finite_forward_and_backward(scene, normalize: bool) -> None:
    means, quats, log_scales, logits, sh_degree, dtype, focal = scene
    n = means.shape[0]
    params = [means, quats, log_scales, logits]
    for p in params:
        p.requires_grad_(True)
    sh = torch.linspace(-1, 1, n * 16 * 3, dtype=dtype).reshape(n, 16, 3).requires_grad_(True)
    ks = torch.tensor([[[focal, 0, W / 2], [0, focal, H / 2], [0, 0, 1]]], dtype=dtype)
    out = rasterize(means, quats, log_scales, torch.sigmoid(logits), sh, torch.eye(4, dtype=dtype)[None], ks, W, H,
                    sh_degree=sh_degree, log_scales=True, backgrounds=torch.ones(3, dtype=dtype),
                    subset_mask=torch.arange(n) % 2 == 0, normalize_depth=normalize)
    for name in ("colors", "alphas", "depths", "subset_alphas", "means2d"):
        assert torch.isfinite(getattr(out, name)).all(), name
    assert torch.all((out.alphas >= 0) & (out.alphas <= 1))
    assert torch.all(out.subset_alphas <= out.alphas + 1e-6)
    loss = out.colors.sum() + out.alphas.sum() + out.depths.sum() + out.subset_alphas.sum()
    loss.backward()
    for name, p in zip(("means", "quats", "log_scales", "logits", "sh"), params + [sh]):
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    assert torch.isfinite(out.means2d.grad).all()


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 40), st.floats(0.0, 1.0))
def test_random_scenes_match_dense_reference(seed: int, n: int, opacity_floor: float) -> None:
    g = torch.Generator().manual_seed(seed)
    dt = torch.float64
    means = torch.randn(n, 3, generator=g, dtype=dt) * 0.5 + torch.tensor([0, 0, 2.5], dtype=dt)
    scales = torch.exp(torch.randn(n, 3, generator=g, dtype=dt) - 2.5)
    quats = torch.randn(n, 4, generator=g, dtype=dt)
    opac = opacity_floor + (1 - opacity_floor) * torch.rand(n, generator=g, dtype=dt)
    colors = torch.rand(n, 2, generator=g, dtype=dt)
    ks = torch.tensor([[[14.0, 0, W / 2], [0, 14.0, H / 2], [0, 0, 1]]], dtype=dt)
    vm = torch.eye(4, dtype=dt)[None]
    out = rasterize(means, quats, scales, opac, colors, vm, ks, W, H)
    ref = dense_rasterize(means, quats, scales, opac, colors, vm, ks, W, H)
    for name in ("colors", "alphas", "depths"):
        assert float((getattr(out, name) - getattr(ref, name)).abs().max()) < 1e-6, name
    assert torch.equal(out.radii, ref.radii)
