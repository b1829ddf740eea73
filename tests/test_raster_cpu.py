"""The compiled CPU backend against the torch backend (an independent implementation of the same
semantics whose gradients come from autograd), plus determinism and the build-failure path."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from smokeseer.raster import rasterize
from tests.raster_reference import random_scene
from tests.test_raster import weighted_loss

ROOT = Path(__file__).resolve().parents[1]


def render_with_grads(backend: str, scene, d_sh: int | None, mask, bg, weights):
    means, quats, scales, opac, colors, vm, ks, w, h = scene
    leaves = [t.detach().clone().requires_grad_(True) for t in (means, quats, scales, opac, colors, vm)]
    out = rasterize(*leaves, ks, w, h, sh_degree=d_sh, subset_mask=mask, backgrounds=bg, backend=backend)
    weighted_loss(out, weights).backward()
    return out, [p.grad for p in leaves] + [out.means2d.grad]


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-9), (torch.float32, 1e-4)])
@pytest.mark.parametrize("d,sh_degree", [(3, 2), (1, None), (7, None)])
def test_outputs_and_gradients_match_torch_backend(dtype: torch.dtype, tol: float, d: int, sh_degree: int | None) -> None:
    """Three cameras, subset alpha, depth, background; D = 3 (SH), 1 (thermal) and 7 (the kernel's
    generic feature-count path). Gradients agree to ``tol`` relative to each tensor's largest entry."""
    scene = list(random_scene(21, 400, c=3, d=d, dtype=dtype, scale=(0.02, 0.25)))
    if sh_degree is not None:
        scene[4] = torch.randn(400, 9, d, dtype=dtype, generator=torch.Generator().manual_seed(3)) * 0.3
    mask = torch.rand(400, generator=torch.Generator().manual_seed(4)) < 0.3
    bg = torch.rand(3, d, dtype=dtype, generator=torch.Generator().manual_seed(5))
    weights = torch.randn(3, scene[8], scene[7], d + 3, dtype=dtype, generator=torch.Generator().manual_seed(6))
    fast, fast_grads = render_with_grads("cpu", scene, sh_degree, mask, bg, weights)
    ref, ref_grads = render_with_grads("torch", scene, sh_degree, mask, bg, weights)
    assert fast.n_pairs == ref.n_pairs > 0
    for name in ("colors", "alphas", "depths", "subset_alphas"):
        a, b = getattr(fast, name), getattr(ref, name)
        assert float((a - b).detach().abs().max()) <= tol, name
    names = ("means", "quats", "scales", "opacities", "colors", "viewmats", "means2d")
    for name, a, b in zip(names, fast_grads, ref_grads):
        scale = float(b.abs().max())
        assert scale > 0, name
        assert float((a - b).abs().max()) <= tol * scale, f"{name}: {float((a - b).abs().max()) / scale:.2e}"


def test_equal_depths_blend_in_index_order() -> None:
    """The kernel sorts front to back itself (a radix sort of the float64 view z): Gaussians at
    exactly equal depth, and +0.0 against -0.0 keys, must keep index order as the torch backend's
    stable argsort does. Overlapping opaque splats with distinct colours make any swap visible."""
    from smokeseer.raster.cpu_backend import composite_tiles
    from smokeseer.raster.projection import Projection
    from smokeseer.raster.torch_backend import composite

    n = 64
    gen = torch.Generator().manual_seed(7)
    xy = torch.rand(1, n, 2, generator=gen, dtype=torch.float64) * 12 + 2
    depths = torch.tensor([1.0, 2.0, 0.0, -0.0] * (n // 4), dtype=torch.float64)[None]
    proj = Projection(means2d=xy, conics=torch.tensor([0.05, 0.0, 0.05], dtype=torch.float64).expand(1, n, 3).clone(),
                      depths=depths, radii=torch.full((1, n), 9.0, dtype=torch.float64),
                      visible=torch.ones(1, n, dtype=torch.bool), sort_depths=depths)
    opac = torch.full((n,), 0.7, dtype=torch.float64)
    colors = torch.rand(n, 3, generator=gen, dtype=torch.float64)
    fast = composite_tiles(proj, opac, colors, 16, 16, render_depth=True, subset_mask=None)
    ref = composite(proj, opac, colors, 16, 16, render_depth=True, subset_mask=None)
    assert fast.n_pairs == ref.n_pairs > 0
    assert float((fast.colors - ref.colors).abs().max()) <= 1e-12


def test_float32_projection_is_the_same_in_both_backends() -> None:
    """Both projections evaluate in float64 and round once, so float32 outputs are bitwise equal,
    and an isotropic Gaussian's rotation gradient (truly zero) stays at float64 rounding in both.
    In float32 that gradient was ~1e-7 noise, which Adam (eps 1e-15) turns into full-size steps."""
    from smokeseer.raster.cpu_backend import project_compiled
    from smokeseer.raster.projection import project_gaussians

    means, quats, scales, _, _, vm, ks, w, h = random_scene(24, 600, c=2, dtype=torch.float32)
    quats = quats.clone()
    quats[:300] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    scales = scales.clone()
    scales[:300] = scales[:300, :1]
    results = []
    for project in (project_compiled, project_gaussians):
        leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales)]
        proj = project(*leaves, vm, ks, w, h, 0.01, 100.0)
        assert proj.sort_depths is not None and proj.sort_depths.dtype == torch.float64
        (proj.means2d.sum() + (proj.conics * torch.tensor([1.0, -2.0, 0.5])).sum() + proj.depths.sum()).backward()
        results.append((proj, leaves[1].grad))
    (fast, fast_q), (ref, ref_q) = results
    for name in ("means2d", "conics", "depths", "radii", "visible", "sort_depths"):
        assert torch.equal(getattr(fast, name), getattr(ref, name)), name
    assert float(ref_q[300:].abs().max()) > 1e-3
    for grad in (fast_q, ref_q):
        assert float(grad[:300].abs().max()) < 1e-9


def run_once(threads: int) -> list[torch.Tensor]:
    torch.set_num_threads(threads)
    scene = random_scene(22, 3000, c=2, width=96, height=80, dtype=torch.float32, scale=(0.02, 0.2))
    leaves = [t.clone().requires_grad_(True) for t in scene[:6]]
    out = rasterize(*leaves, *scene[6:], backend="cpu")
    weights = torch.randn(2, 80, 96, 5, generator=torch.Generator().manual_seed(7))
    weighted_loss(out, weights).backward()
    return [out.colors, out.alphas, out.depths, out.means2d.grad] + [p.grad for p in leaves]


@pytest.mark.parametrize("threads", [1, 2])
def test_same_bytes_for_same_inputs_and_thread_count(threads: int) -> None:
    before = torch.get_num_threads()
    try:
        first, again = run_once(threads), run_once(threads)
    finally:
        torch.set_num_threads(before)
    for a, b in zip(first, again):
        assert torch.equal(a, b)


def test_cpu_backend_rejects_other_devices_by_name() -> None:
    if not torch.cuda.is_available():
        pytest.skip("needs a second device type")
    scene = [t.cuda() if isinstance(t, torch.Tensor) else t for t in random_scene(23, 8)]
    with pytest.raises(ValueError, match="backend='cpu'"):
        rasterize(*scene, backend="cpu")


@pytest.mark.parametrize("module, kernel, what", [
    ("smokeseer.raster.extension", "TILE_RASTER", "the CPU tile rasterizer"),
    ("smokeseer.model.planes", "PLANE_FEATURES", "the CPU plane-field lookups")])
def test_failed_build_is_one_clear_error(tmp_path: Path, module: str, kernel: str, what: str) -> None:
    """A broken compiler stops with KernelBuildError naming it; nothing falls back to torch."""
    env = {**os.environ, "CXX": "/bin/false", "TORCH_EXTENSIONS_DIR": str(tmp_path)}
    code = f"from {module} import load_kernel, {kernel}; load_kernel({kernel})"
    proc = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode != 0
    last = proc.stderr.strip().splitlines()[-1]
    assert "KernelBuildError" in last and f"could not build {what}" in last, proc.stderr[-2000:]
    assert "/bin/false" in last


def test_each_torch_installation_keeps_its_own_build(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two virtual environments (two torch installations) get two build folders: with one shared
    folder each load from the other environment rewrote ninja's command line (its torch include
    paths) and silently recompiled the kernel (34 s inside a timed run)."""
    from smokeseer.raster import extension

    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    here, _ = extension.build_directory()
    assert extension.build_directory()[0] == here
    monkeypatch.setattr(torch, "__file__", str(tmp_path / "other-venv" / "torch" / "__init__.py"))
    assert extension.build_directory()[0] != here


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_compiled_sh_colours_match_the_torch_basis_and_finite_differences(degree: int) -> None:
    """The C++ SH colours against the torch closed form (``sh.eval_sh`` + 0.5, clamped at 0) and
    its autograd, in float64: two cameras, more coefficients than the degree uses, colours clamped
    at 0, and one Gaussian at a camera centre (a zero direction: DC only). Then torch's finite
    differences on the compiled Function itself."""
    from smokeseer.raster.api import view_colors
    from smokeseer.raster.cpu_backend import sh_colors
    gen = torch.Generator().manual_seed(degree)
    coeffs = torch.randn(40, 16, 3, dtype=torch.float64, generator=gen) * 0.6
    means = torch.randn(40, 3, dtype=torch.float64, generator=gen)
    viewmats = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    viewmats[:, :3, 3] = torch.randn(2, 3, dtype=torch.float64, generator=gen)
    means[7] = -viewmats[0, :3, 3]  # the first camera's centre
    weights = torch.randn(2, 40, 3, dtype=torch.float64, generator=gen)
    results = []
    for compiled in (True, False):
        c, m = coeffs.clone().requires_grad_(), means.clone().requires_grad_()
        out = view_colors(c, m, viewmats, degree, compiled=compiled)
        (out * weights).sum().backward()
        results.append((out.detach(), c.grad, torch.zeros_like(m) if m.grad is None else m.grad))
    (fast, fast_c, fast_m), (ref, ref_c, ref_m) = results
    assert bool((ref == 0).any()) and bool((ref > 0).any())  # some colours clamped, some not
    assert torch.allclose(fast, ref, atol=1e-12, rtol=0)
    assert torch.allclose(fast_c, ref_c, atol=1e-12, rtol=0)
    assert torch.allclose(fast_m, ref_m, atol=1e-10, rtol=0)
    assert bool(fast_c[:, (degree + 1) ** 2:].eq(0).all())
    campos = -viewmats[:, :3, 3]
    c, m = coeffs[:6].clone().requires_grad_(), (means[:6] + 0.1).clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda a, b: sh_colors(a, b, campos, degree), (c, m), eps=1e-6, atol=1e-7)
