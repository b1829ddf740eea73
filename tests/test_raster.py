"""The torch rasterizer against the dense all-pairs reference, finite differences and hand-made cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.special import sph_harm_y

import smokeseer.raster.torch_backend as torch_backend
from smokeseer.raster import eval_sh, rasterize
from smokeseer.raster.api import view_colors
from tests.raster_reference import dense_loss_backward, dense_rasterize, every_cpu_backend  # noqa: F401 (fixture)
from tests.raster_reference import random_scene

pytestmark = pytest.mark.usefixtures("every_cpu_backend")

F64 = torch.float64


def assert_matches_dense(out, ref, tol: float) -> float:
    worst = 0.0
    for name in ("colors", "alphas", "depths", "subset_alphas", "means2d"):
        a, b = getattr(out, name), getattr(ref, name)
        if a is None:
            assert b is None
            continue
        err = float((a - b).abs().max()) if a.numel() else 0.0
        assert err <= tol, f"{name}: max abs diff {err}"
        worst = max(worst, err)
    assert torch.equal(out.radii, ref.radii)
    assert torch.equal(out.visible, ref.visible)
    return worst


@pytest.mark.parametrize("seed,n,d", [(0, 150, 3), (1, 400, 1), (2, 60, 5)])
def test_matches_dense_reference_float64(seed: int, n: int, d: int) -> None:
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(seed, n, d=d)
    mask = torch.rand(n, generator=torch.Generator().manual_seed(seed)) < 0.4
    bg = torch.rand(vm.shape[0], d, dtype=F64)
    out = rasterize(means, quats, scales, opac, colors, vm, ks, w, h, backgrounds=bg, subset_mask=mask)
    ref = dense_rasterize(means, quats, scales, opac, colors, vm, ks, w, h, backgrounds=bg, subset_mask=mask)
    assert out.n_pairs > 0 and float(out.alphas.max()) > 0.9  # the scene exercises overlap
    assert_matches_dense(out, ref, 1e-6)


def test_matches_dense_with_early_termination_and_tiny_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Dense, nearly opaque scene: many pixels stop early; chunking must not change anything."""
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(3, 500, c=1, spread=0.5, scale=(0.05, 0.3))
    opac = 0.6 + 0.4 * opac
    ref = dense_rasterize(means, quats, scales, opac, colors, vm, ks, w, h)
    full = rasterize(means, quats, scales, opac, colors, vm, ks, w, h)
    monkeypatch.setattr(torch_backend, "PAIR_CHUNK", 997)
    chunked = rasterize(means, quats, scales, opac, colors, vm, ks, w, h)
    assert float((ref.alphas > 0.999).double().mean()) > 0.5  # most pixels reach termination
    assert_matches_dense(full, ref, 1e-6)
    assert_matches_dense(chunked, ref, 1e-6)
    assert chunked.n_pairs == full.n_pairs


def test_sh_render_matches_dense_reference() -> None:
    means, quats, scales, opac, _, vm, ks, w, h = random_scene(4, 120)
    sh = torch.randn(120, 16, 3, dtype=F64) * 0.3
    for degree in range(4):
        out = rasterize(means, quats, scales, opac, sh, vm, ks, w, h, sh_degree=degree)
        per_view = view_colors(sh, means, vm, degree)
        assert per_view.shape == (2, 120, 3)
        ref = dense_rasterize(means, quats, scales, opac, per_view, vm, ks, w, h)
        assert_matches_dense(out, ref, 1e-6)


def test_float32_close_to_float64() -> None:
    scene = random_scene(5, 200)
    ref = dense_rasterize(*scene)
    f32 = [t.float() for t in scene[:7]] + list(scene[7:])
    out = rasterize(*f32)
    assert out.colors.dtype == torch.float32
    assert float((out.colors.double() - ref.colors).abs().max()) < 1e-4
    assert float((out.depths.double() - ref.depths).abs().max()) < 1e-3


def real_sh_scipy(degree: int, dirs: np.ndarray) -> np.ndarray:
    """Real SH from scipy's complex ones (Condon-Shortley phase included), m = -l..l per band."""
    theta = np.arccos(np.clip(dirs[:, 2], -1, 1))
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    cols = []
    for l in range(degree + 1):
        for m in range(-l, l + 1):
            y = sph_harm_y(l, abs(m), theta, phi)
            if m > 0:
                cols.append(math.sqrt(2) * y.real)
            elif m < 0:
                cols.append(math.sqrt(2) * y.imag)
            else:
                cols.append(y.real)
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_eval_sh_matches_scipy(degree: int) -> None:
    rng = np.random.default_rng(degree)
    dirs = rng.normal(size=(64, 3)) * rng.uniform(0.1, 10, size=(64, 1))  # not unit length
    k = (degree + 1) ** 2
    coeffs = rng.normal(size=(64, 16, 2))
    expected = np.einsum("nk,nkd->nd", real_sh_scipy(degree, dirs / np.linalg.norm(dirs, axis=1, keepdims=True)), coeffs[:, :k])
    got = eval_sh(degree, torch.from_numpy(coeffs), torch.from_numpy(dirs)).numpy()
    np.testing.assert_allclose(got, expected, atol=1e-12)


def weighted_loss(out, weights: torch.Tensor) -> torch.Tensor:
    parts = [out.colors, out.alphas, out.depths] + ([out.subset_alphas] if out.subset_alphas is not None else [])
    return (torch.cat(parts, dim=-1) * weights).sum()


def central_fd_check(fn, params: list[torch.Tensor], h: float = 1e-6, per_param: int = 40) -> float:
    """Largest |analytic - central FD| / (1 + |FD|) over up to ``per_param`` random entries of each
    parameter (all of them when it is smaller)."""
    params = [p.detach().clone().requires_grad_(True) for p in params]
    fn(*params).backward()
    worst = 0.0
    pick = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for p in params:
            flat = p.view(-1)
            for i in torch.randperm(flat.numel(), generator=pick)[:per_param].tolist():
                old = float(flat[i])
                flat[i] = old + h
                up = float(fn(*params))
                flat[i] = old - h
                down = float(fn(*params))
                flat[i] = old
                fd = (up - down) / (2 * h)
                worst = max(worst, abs(float(p.grad.view(-1)[i]) - fd) / (1 + abs(fd)))
    return worst


@pytest.mark.parametrize("seed,log_scales", [(10, False), (11, True)])
def test_gradients_match_central_finite_differences(seed: int, log_scales: bool) -> None:
    means, quats, scales, opac, colors, vm, ks, _, _ = random_scene(seed, 10, c=2, scale=(0.05, 0.2), spread=0.4)
    opac = 0.1 + 0.8 * opac
    w, h = 20, 16
    ks[:, 0, 2], ks[:, 1, 2], ks[:, 0, 0], ks[:, 1, 1] = w / 2, h / 2, 1.5 * w, 1.5 * w
    mask = torch.arange(10) % 3 == 0
    bg = torch.tensor([0.2, 0.5, 0.1], dtype=F64)
    weights = torch.randn(2, h, w, 6, dtype=F64, generator=torch.Generator().manual_seed(seed))
    s_in = torch.log(scales) if log_scales else scales

    def loss(m, q, s, o, c, v):
        return weighted_loss(rasterize(m, q, s, o, c, v, ks, w, h, backgrounds=bg, subset_mask=mask,
                                       log_scales=log_scales), weights)

    assert central_fd_check(loss, [means, quats, s_in, opac, colors, vm]) < 1e-5


def test_sh_gradients_match_central_finite_differences() -> None:
    means, quats, scales, opac, _, vm, ks, _, _ = random_scene(12, 6, c=2, scale=(0.05, 0.2), spread=0.4)
    w, h = 16, 12
    ks[:, 0, 2], ks[:, 1, 2], ks[:, 0, 0], ks[:, 1, 1] = w / 2, h / 2, 1.5 * w, 1.5 * w
    sh = torch.randn(6, 16, 3, dtype=F64, generator=torch.Generator().manual_seed(1)) * 0.2
    weights = torch.randn(2, h, w, 5, dtype=F64)

    def loss(m, c):
        return weighted_loss(rasterize(m, quats, scales, 0.2 + 0.7 * opac, c, vm, ks, w, h, sh_degree=3), weights)

    assert central_fd_check(loss, [means, sh]) < 1e-5


def test_all_gradients_match_dense_reference_on_a_larger_scene() -> None:
    """Beyond FD on tiny scenes: every parameter's gradient (viewmats too) on 300 Gaussians."""
    scene = random_scene(18, 300)
    weights = torch.randn(2, scene[8], scene[7], 5, dtype=F64, generator=torch.Generator().manual_seed(2))
    fast = [t.clone().requires_grad_(True) for t in scene[:6]]
    out = rasterize(*fast, scene[6], scene[7], scene[8])
    weighted_loss(out, weights).backward()
    ref = [t.clone().requires_grad_(True) for t in scene[:6]]
    dense_loss_backward(*ref, scene[6], scene[7], scene[8], weights, pixel_chunk=300)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colors", "viewmats"), fast, ref):
        assert float(b.grad.abs().max()) > 0, name
        torch.testing.assert_close(a.grad, b.grad, atol=1e-8, rtol=1e-8, msg=name)


def test_means2d_gradient_matches_reference() -> None:
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(13, 80)
    weights = torch.randn(2, h, w, 5, dtype=F64)
    out = rasterize(means.requires_grad_(True), quats, scales, opac, colors, vm, ks, w, h)
    weighted_loss(out, weights).backward()
    offset = torch.zeros(2, 80, 2, dtype=F64, requires_grad=True)
    ref = dense_rasterize(means.detach(), quats, scales, opac, colors, vm, ks, w, h, means2d_offset=offset)
    weighted_loss(ref, weights).backward()
    assert out.means2d.grad is not None
    assert float(offset.grad.abs().max()) > 1e-3
    torch.testing.assert_close(out.means2d.grad, offset.grad, atol=1e-9, rtol=1e-7)


def isotropic(n_per_pixel: list[float], z: list[float], width: int = 5, height: int = 5):
    """Large isotropic Gaussians centred on the middle pixel centre, with the given opacities."""
    n = len(n_per_pixel)
    means = torch.tensor([[0.0, 0.0, zi] for zi in z], dtype=F64)
    quats = torch.tensor([[1.0, 0, 0, 0]] * n, dtype=F64)
    scales = torch.full((n, 3), 0.5, dtype=F64)
    ks = torch.tensor([[[10.0, 0, width / 2], [0, 10.0, height / 2], [0, 0, 1]]], dtype=F64)
    return means, quats, scales, torch.tensor(n_per_pixel, dtype=F64), torch.eye(4, dtype=F64)[None], ks


def test_early_termination_clamp_and_skip_by_hand() -> None:
    """Centre pixel, front to back: alphas 0.98, 0.98 (T=4e-4), then 0.9 would take T to 4e-5 < 1e-4,
    so it and everything behind it are not blended. Input order is scrambled (depth decides)."""
    means, quats, scales, opac, vm, ks = isotropic([0.9, 0.98, 0.5, 0.98], [4.0, 1.0, 5.0, 2.0])
    colors = torch.tensor([[0.0, 0, 1], [1.0, 0, 0], [1.0, 1, 1], [0.0, 1, 0]], dtype=F64)
    bg = torch.tensor([0.3, 0.3, 0.3], dtype=F64)
    out = rasterize(means, quats, scales, opac, colors, vm, ks, 5, 5, backgrounds=bg)
    ref = dense_rasterize(means, quats, scales, opac, colors, vm, ks, 5, 5, backgrounds=bg)
    t_final = 0.02 * 0.02
    expected = 0.98 * colors[1] + 0.02 * 0.98 * colors[3] + t_final * bg
    torch.testing.assert_close(out.colors[0, 2, 2], expected, atol=1e-12, rtol=0)
    torch.testing.assert_close(ref.colors[0, 2, 2], expected, atol=1e-12, rtol=0)
    assert abs(float(out.alphas[0, 2, 2, 0]) - (1 - t_final)) < 1e-12
    assert abs(float(out.depths[0, 2, 2, 0]) - (0.98 * 1.0 + 0.02 * 0.98 * 2.0)) < 1e-12

    means, quats, scales, opac, vm, ks = isotropic([1.0, 0.003], [1.0, 2.0])
    out = rasterize(means, quats, scales, opac, torch.ones(2, 1, dtype=F64), vm, ks, 5, 5)
    assert abs(float(out.alphas[0, 2, 2, 0]) - 0.99) < 1e-12  # clamped at 0.99; 0.003 < 1/255 skipped


def test_depth_normalization_and_subset_alpha() -> None:
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(14, 200)
    mask = torch.rand(200, generator=torch.Generator().manual_seed(0)) < 0.5
    out = rasterize(means, quats, scales, opac, colors, vm, ks, w, h, subset_mask=mask, normalize_depth=True)
    raw = rasterize(means, quats, scales, opac, colors, vm, ks, w, h, subset_mask=~mask)
    covered = out.alphas > 1e-6
    torch.testing.assert_close(out.depths[covered], (raw.depths / raw.alphas)[covered])
    assert torch.all(out.depths[~covered] == 0)
    # The two subsets' weights partition the joint composite, and neither is a separate render.
    torch.testing.assert_close(out.subset_alphas + raw.subset_alphas, out.alphas, atol=1e-12, rtol=0)
    alone = rasterize(means[mask], quats[mask], scales[mask], opac[mask], colors[mask], vm, ks, w, h)
    assert float((alone.alphas - out.subset_alphas).max()) > 1e-2
    assert torch.all(out.subset_alphas <= alone.alphas + 1e-12)  # occlusion only removes weight


def smoke_in_front(seed: int, n: int):
    """A random scene whose masked ("smoke") half sits nearer the cameras with high opacity, so the
    joint composite stops early at many pixels while the unmasked half alone does not."""
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(seed, n)
    mask = torch.arange(n) % 2 == 0
    means = means.clone()
    means[mask, 2] -= 1.5
    scales = torch.where(mask[:, None], 3 * scales, scales)
    opac = torch.where(mask, 0.6 + 0.39 * opac, opac)
    return means, quats, scales, opac, colors, vm, ks, w, h, mask


def test_rest_alone_is_a_separate_render_from_the_same_pass() -> None:
    means, quats, scales, opac, colors, vm, ks, w, h, mask = smoke_in_front(16, 300)
    params = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac)]
    joint = rasterize(*params, colors, vm, ks, w, h, subset_mask=mask, normalize_depth=True, render_rest_alone=True)
    plain = rasterize(means, quats, scales, opac, colors, vm, ks, w, h, subset_mask=mask, normalize_depth=True)
    for name in ("colors", "alphas", "depths", "subset_alphas"):
        assert torch.equal(getattr(joint, name), getattr(plain, name)), name  # the flag changes nothing else
    stopped = joint.alphas > 1 - 1e-3
    assert bool((stopped & (joint.rest_alphas < 0.9)).any())  # pixels where the joint walk ends first
    weights = torch.rand(2, h, w, 8, generator=torch.Generator().manual_seed(1), dtype=F64)
    (weighted_loss(joint, weights[..., :6])
     + (torch.cat([joint.rest_depths, joint.rest_alphas], -1) * weights[..., 6:]).sum()).backward()

    ref_params = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac)]
    ref_joint = rasterize(*ref_params, colors, vm, ks, w, h, subset_mask=mask, normalize_depth=True)
    keep = ~mask
    alone = rasterize(*(p[keep] for p in ref_params), colors[keep], vm, ks, w, h, normalize_depth=True)
    torch.testing.assert_close(joint.rest_depths, alone.depths, rtol=0, atol=1e-12)
    torch.testing.assert_close(joint.rest_alphas, alone.alphas, rtol=0, atol=1e-12)
    (weighted_loss(ref_joint, weights[..., :6])
     + (torch.cat([alone.depths, alone.alphas], -1) * weights[..., 6:]).sum()).backward()
    for got, want in zip(params, ref_params):
        torch.testing.assert_close(got.grad, want.grad, rtol=1e-9, atol=1e-12)


def test_rest_alone_gradients_match_central_finite_differences() -> None:
    means, quats, scales, opac, colors, vm, ks, w, h, mask = smoke_in_front(17, 12)
    weights = torch.rand(2, h, w, 2, generator=torch.Generator().manual_seed(2), dtype=F64)

    def loss(m, q, s, o):
        out = rasterize(m, q, s, o, colors, vm, ks, w, h, subset_mask=mask, normalize_depth=False,
                        render_rest_alone=True)
        return (torch.cat([out.rest_depths, out.rest_alphas], -1) * weights).sum()

    assert central_fd_check(loss, [means, quats, scales, opac]) < 1e-5


def test_cameras_are_independent_and_backgrounds_broadcast() -> None:
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(15, 150, c=3)
    bg = torch.rand(3, 3, dtype=F64)
    both = rasterize(means, quats, scales, opac, colors, vm, ks, w, h, backgrounds=bg)
    for i in range(3):
        one = rasterize(means, quats, scales, opac, colors, vm[i:i + 1], ks[i:i + 1], w, h, backgrounds=bg[i])
        torch.testing.assert_close(one.colors[0], both.colors[i], atol=1e-12, rtol=0)
        assert torch.equal(one.radii[0], both.radii[i])


def test_near_plane_culling() -> None:
    means, quats, scales, opac, vm, ks = isotropic([0.5, 0.5, 0.5, 0.5], [0.5, 0.01, 0.2, -1.0])
    out = rasterize(means, quats, scales * 0.01, opac, torch.ones(4, 1, dtype=F64), vm, ks, 5, 5,
                    near_plane=0.2, far_plane=100.0)
    assert out.visible[0].tolist() == [True, False, True, False]
    assert out.radii[0, 1] == 0 and out.radii[0, 3] == 0
    assert torch.all(out.means2d[0, 1] == 0)


def test_empty_scene_returns_background_with_gradients() -> None:
    means = torch.zeros(0, 3, requires_grad=True)
    colors = torch.zeros(0, 3, requires_grad=True)
    bg = torch.tensor([0.1, 0.2, 0.3])
    ks = torch.tensor([[[8.0, 0, 4], [0, 8.0, 4], [0, 0, 1]]])
    out = rasterize(means, torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), colors,
                    torch.eye(4)[None], ks, 8, 8, backgrounds=bg, subset_mask=torch.zeros(0, dtype=torch.bool))
    assert torch.equal(out.colors, bg.expand(1, 8, 8, 3))
    assert torch.all(out.alphas == 0) and torch.all(out.subset_alphas == 0)
    out.colors.sum().backward()
    assert means.grad is not None and means.grad.shape == (0, 3)


@pytest.mark.parametrize("field,mutate,match", [
    ("quats", lambda a: a["quats"].__setitem__((3,), 0.0), "quats"),
    ("means", lambda a: a["means"].__setitem__((2, 1), float("nan")), "means"),
    ("colors", lambda a: a["colors"].__setitem__((0, 0), float("inf")), "colors"),
    ("scales", lambda a: a["scales"].__setitem__((1, 2), -0.1), "scales"),
    ("opacities", lambda a: a["opacities"].__setitem__((0,), 1.5), "opacities"),
    ("viewmats", lambda a: a["viewmats"].__setitem__((0, 0, 3), float("nan")), "viewmats"),
])
def test_invalid_input_raises_clear_error(field: str, mutate, match: str) -> None:
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(16, 8)
    args = {"means": means, "quats": quats, "scales": scales, "opacities": opac, "colors": colors,
            "viewmats": vm, "Ks": ks}
    mutate(args)
    with pytest.raises(ValueError, match=match):
        rasterize(**args, width=w, height=h)


def test_shape_and_backend_errors() -> None:
    means, quats, scales, opac, colors, vm, ks, w, h = random_scene(17, 8)
    with pytest.raises(ValueError, match="colors"):
        rasterize(means, quats, scales, opac, colors, vm, ks, w, h, sh_degree=1)
    with pytest.raises(ValueError, match="subset_mask"):
        rasterize(means, quats, scales, opac, colors, vm, ks, w, h, subset_mask=torch.ones(8))
    with pytest.raises(ValueError, match="render_rest_alone needs a subset_mask"):
        rasterize(means, quats, scales, opac, colors, vm, ks, w, h, render_rest_alone=True)
    with pytest.raises(ValueError, match="render_rest_alone needs a subset_mask and render_depth"):
        rasterize(means, quats, scales, opac, colors, vm, ks, w, h, subset_mask=torch.ones(8, dtype=torch.bool),
                  render_depth=False, render_rest_alone=True)
    with pytest.raises(ValueError, match="backend"):
        rasterize(means, quats, scales, opac, colors, vm, ks, w, h, backend="cuda-magic")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="gsplat"):
            rasterize(means, quats, scales, opac, colors, vm, ks, w, h, backend="gsplat")
