"""deform.kind=planes: the plane field against finite differences, an analytic linear field and
torch's grid_sample; its smoothness terms; its settings; a Stage-3 run that stops and resumes."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from torch.func import functional_call

from smokeseer.cli import main
from smokeseer.config import DeformConfig, make_config
from smokeseer.model.planes import (PlaneField, plane_product, plane_product_reference, time_curvature,
                                    total_variation)
from tests.test_smokeseer_data import write_splat_dataset
from tests.test_trainer import TINY, run_stopped_and_resumed

SMALL = DeformConfig(kind="planes", planes_resolution=3, planes_levels=2, planes_time_resolution=3,
                     planes_features=2, planes_head_width=4, predict_rotation_scale=True)


def _field(cfg: DeformConfig = SMALL, dtype: torch.dtype = torch.float64) -> PlaneField:
    torch.manual_seed(0)
    field = PlaneField(cfg, torch.tensor([-1.0, -2.0, 0.0]), torch.tensor([1.0, 0.0, 3.0]), 2.0,
                       torch.device("cpu")).to(dtype)
    torch.nn.init.normal_(field.head.weight, std=0.5)
    for p in field.time:  # away from their all-ones start, so time changes the features
        p.data.uniform_(0.5, 1.5)
    return field


def test_field_gradient_matches_finite_differences() -> None:
    """Every parameter's gradient (planes through the compiled lookups, hidden layer, head) of
    the offsets at two times against central differences, float64, a 3-cell grid; positions
    inside and outside the domain (clamped)."""
    field = _field()
    means = torch.tensor([[0.1, -1.2, 1.0], [-0.9, -0.1, 2.9], [1.5, -2.5, 1.7], [0.33, -0.77, 0.2]],
                         dtype=torch.float64)
    names = [n for n, _ in field.named_parameters()]

    def offsets(*params: torch.Tensor) -> torch.Tensor:
        state = dict(zip(names, params))
        return torch.cat([d for t in (0.2, 0.85) for d in functional_call(field, state, (means, t))], 1)

    params = tuple(p.detach().clone().requires_grad_() for p in field.parameters())
    assert torch.autograd.gradcheck(offsets, params, eps=1e-6, atol=1e-6, fast_mode=True)


def test_lookup_is_exact_on_a_linear_field() -> None:
    """Bilinear interpolation reproduces an affine function of the plane's coordinates exactly:
    three planes a + b·x + c·y give the product of the three affine values, and outside the
    domain the value at the clamped coordinate; the kernel and grid_sample alike."""
    h, w, f = 5, 7, 3
    ab = torch.tensor([[0.5, 0.2, -0.3], [1.0, -0.4, 0.1], [2.0, 0.3, 0.25]], dtype=torch.float64)  # plane: a, b, c
    scale = torch.tensor([1.0, 2.0, -1.5], dtype=torch.float64)  # feature f: scale_f × the plane's value
    x = torch.linspace(-1, 1, w, dtype=torch.float64)
    y = torch.linspace(-1, 1, h, dtype=torch.float64)
    planes = torch.stack([(a + b * x[None, :] + c * y[:, None])[..., None] * scale for a, b, c in ab])
    torch.manual_seed(1)
    coords = torch.rand(40, 3, 2, dtype=torch.float64) * 3.0 - 1.5
    clamped = coords.clamp(-1, 1)
    expected = torch.ones(40, f, dtype=torch.float64)
    for p, (a, b, c) in enumerate(ab):
        expected = expected * (a + b * clamped[:, p, 0] + c * clamped[:, p, 1])[:, None] * scale
    for lookup in (plane_product, plane_product_reference):
        torch.testing.assert_close(lookup(planes, coords), expected, rtol=0, atol=1e-12)


def test_kernel_matches_grid_sample_in_float32() -> None:
    """The compiled lookups (the CPU path) against torch's grid_sample (the path elsewhere), values
    and planes' gradients, at the standard resolution's shapes, points inside and outside."""
    torch.manual_seed(2)
    planes = torch.rand(3, 16, 64, 16, requires_grad=True)
    coords = torch.rand(3000, 3, 2) * 2.4 - 1.2
    grad = torch.randn(3000, 16)
    ours = plane_product(planes, coords)
    (g_ours,) = torch.autograd.grad(ours, planes, grad)
    ref = plane_product_reference(planes, coords)
    (g_ref,) = torch.autograd.grad(ref, planes, grad)
    torch.testing.assert_close(ours, ref, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(g_ours, g_ref, rtol=1e-5, atol=2e-5)


def test_offsets_start_at_zero_and_the_domain_is_kept() -> None:
    """A new field moves nothing (zero head output) at any time, inside or outside its domain;
    the domain travels in its state, so a field loaded into one built for another box agrees."""
    field = PlaneField(DeformConfig(kind="planes", predict_rotation_scale=True), torch.tensor([-1.0, -1, -1]),
                       torch.tensor([1.0, 1, 1]), 3.0, torch.device("cpu"))
    means = torch.randn(50, 3) * 2
    for t in (0.0, 0.4, 1.0):
        for d in field(means, t):
            assert torch.equal(d, torch.zeros_like(d))
    torch.nn.init.normal_(field.head.weight, std=0.1)
    other = PlaneField(field.cfg, torch.zeros(3), torch.full((3,), 5.0), 3.0, torch.device("cpu"))
    other.load_state_dict(field.state_dict())
    assert torch.equal(other.lo, field.lo) and torch.equal(other.hi, field.hi)
    for a, b in zip(field(means, 0.3), other(means, 0.3)):
        assert torch.equal(a, b)


def test_smoothness_terms_are_zero_on_constant_planes_and_checked() -> None:
    """TV: 0 on a constant plane, s² for a ramp of s per cell along one axis; temporal
    curvature: 0 on a plane linear in time, (2k)² for k·i² along time; gradients of both
    against finite differences; the field's own terms 0 at a constant start."""
    flat = torch.full((3, 4, 5, 2), 0.7, dtype=torch.float64)
    assert total_variation(flat) == 0 and time_curvature(flat) == 0
    ramp = 0.3 * torch.arange(5, dtype=torch.float64)[None, None, :, None].expand(3, 4, 5, 2)
    assert float(total_variation(ramp)) == pytest.approx(0.09, abs=1e-15)
    in_time = torch.arange(4, dtype=torch.float64)[None, :, None, None].expand(3, 4, 5, 2)
    assert float(time_curvature(1.0 + 2.0 * in_time)) == pytest.approx(0.0, abs=1e-15)
    assert float(time_curvature(0.25 * in_time ** 2)) == pytest.approx(0.25, abs=1e-15)
    torch.manual_seed(3)
    noisy = torch.rand(3, 4, 5, 2, dtype=torch.float64, requires_grad=True)
    assert float(total_variation(noisy.detach())) > 0 and float(time_curvature(noisy.detach())) > 0
    assert torch.autograd.gradcheck(total_variation, (noisy,))
    assert torch.autograd.gradcheck(time_curvature, (noisy,))
    field = _field()
    for p in field.space:
        p.data.fill_(0.3)
    for p in field.time:
        p.data.fill_(1.0)
    assert [float(v.detach()) for v in field.smoothness()] == [0.0, 0.0]


@pytest.mark.parametrize("key, value, message", [
    ("deform.planes_resolution", 1, "deform.planes_resolution: must be at least 2, got 1"),
    ("deform.planes_levels", 0, "deform.planes_levels: must be at least 1, got 0"),
    ("deform.planes_resolution", 4096, "deform.planes_resolution: the finest level has 8192 cells"),
    ("deform.planes_tv", -1.0, "deform.planes_tv: must be a number >= 0, got -1.0"),
    ("deform.view_cull_margin", float("nan"), "deform.view_cull_margin: must be a number >= 0"),
])
def test_bad_plane_settings_are_refused(key: str, value: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make_config(overrides={"deform.kind": "planes", key: value})
    with pytest.raises(ValueError, match="deform.view_cull: culls a motion field"):
        make_config(overrides={"deform.kind": "fourier", "deform.view_cull": True})


def test_bad_resolution_is_one_line_before_any_work(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path / "missing"), "--out", str(tmp_path / "run"), "--set", "deform.kind=planes",
                 "--set", "deform.planes_resolution=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["train-and-evaluate: error: deform.planes_resolution: must be at least 2, got 1"]
    assert not (tmp_path / "run").exists()


def test_planes_run_stops_and_resumes_to_the_same_model(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A Stage-3 run of the plane field (with the view cut on) stopped after its checkpoint at
    iteration 6 and started again ends with the same smoke as one that never stopped: the planes,
    the head, the domain and the two-rate optimiser all come back from the checkpoint. The
    planes have moved the smoke by then (smoke PLYs differ between times)."""
    splat = write_splat_dataset(tmp_path / "moving", n_rgb=8, n_thermal=6)
    args = ["--set", "deform.kind=planes", "--set", "deform.planes_resolution=4", "--set", "deform.view_cull=true",
            "--set", "deform.predict_rotation_scale=true"] + TINY
    assert main([str(splat), "--out", str(tmp_path / "whole")] + args) == 0
    state = torch.load(tmp_path / "whole" / "checkpoints" / "stage3.pt", map_location="cpu", weights_only=False)
    assert {"lo", "hi", "space.0", "space.1", "time.0", "time.1", "head.weight"} <= set(state["deform"])
    assert [g["lr_scale"] for g in state["deform_optimizer"]["param_groups"]] == [10.0, 1.0]
    assert state["deform"]["head.weight"].abs().max() > 0
    run = tmp_path / "stopped"
    run_stopped_and_resumed(splat, run, args, 8, monkeypatch)
    plys = sorted((tmp_path / "whole" / "ply").glob("smoke_t*.ply"))
    assert len(plys) >= 2 and plys[0].read_bytes() != plys[-1].read_bytes()
    for ply in plys:
        assert (run / "ply" / ply.name).read_bytes() == ply.read_bytes()
    whole = json.loads((tmp_path / "whole" / "metrics.json").read_text())["metrics"]["psnr"]
    assert json.loads((run / "metrics.json").read_text())["metrics"]["psnr"] == whole
