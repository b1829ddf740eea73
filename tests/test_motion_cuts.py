"""The two cuts of Stage 3's smoke motion: the time-independent part computed once for both
times (``deform.shared_position``) and the view cut (``deform.view_cull``), each against the
uncut computation."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from smokeseer.cli import main
from smokeseer.config import DeformConfig
from smokeseer.model.deform import DeformNetwork
from smokeseer.model.frustum import PAD_PX, near_frustum
from smokeseer.model.gaussians import GaussianSet
from smokeseer.model.scene import SceneModel, add_rgb_sh, init_gaussians, make_smoke, make_view
from tests.test_smokeseer_data import write_splat_dataset
from tests.test_trainer import TINY


@pytest.mark.parametrize("skip", [0, 2, 3])
def test_shared_position_gives_the_offsets_and_gradients_of_two_evaluations(skip: int) -> None:
    """encode once + decode at two times against two plain MLP evaluations: offsets within 1e-6,
    and the weights' gradients of a loss on both times within float rounding; the skip at 0
    (the first layer sees the input twice), at 2 (quick) and at 3 (standard)."""
    torch.manual_seed(skip)
    net = DeformNetwork(DeformConfig(depth=6, width=64, skip_layer=skip, predict_rotation_scale=True), 2.5,
                        torch.device("cpu"))
    torch.nn.init.normal_(net.head.weight, std=0.3)
    means, center = torch.randn(300, 3) * 2, torch.tensor([0.2, -0.1, 0.4])
    weights = torch.randn(300, 10)

    def loss_and_grads(shared: bool) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        net.zero_grad(set_to_none=True)
        enc = net.encode(means, center) if shared else None
        outs = [torch.cat(net.decode(enc, t) if shared else net(means, t, center), 1) for t in (0.13, 0.71)]
        sum((o * weights).sum() for o in outs).backward()
        return outs, [p.grad.clone() for p in net.parameters()]

    plain, g_plain = loss_and_grads(False)
    cut, g_cut = loss_and_grads(True)
    assert plain[0].abs().max() > 0.1  # offsets of a useful size, so the comparison means something
    for a, b in zip(plain, cut):
        torch.testing.assert_close(b, a, rtol=0, atol=1e-6)
    for a, b in zip(g_plain, g_cut):
        torch.testing.assert_close(b, a, rtol=1e-4, atol=1e-5)


def test_stage3_encodes_once_per_iteration_and_decodes_at_both_times(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """With the shared position (the default), every Stage-3 iteration after the warm-up encodes
    the smoke once and decodes it at the RGB and the thermal frame's time."""
    calls = {"encode": 0, "decode": 0}
    for name in calls:
        original = getattr(DeformNetwork, name)

        def counted(self, *args, _original=original, _name=name, **kwargs):
            calls[_name] += 1
            return _original(self, *args, **kwargs)
        monkeypatch.setattr(DeformNetwork, name, counted)
    splat = write_splat_dataset(tmp_path / "moving", n_rgb=8, n_thermal=6)
    assert main([str(splat), "--out", str(tmp_path / "run")] + TINY) == 0
    assert calls == {"encode": 9, "decode": 18}  # 12 iterations, warm-up 0.25 of them


def _scene(offset_std: float) -> tuple[SceneModel, object]:
    """A wide smoke cloud ([-4, 4]³) before a narrow camera at z = -6 looking along +z, so some
    smoke lies outside its view, with an MLP whose offsets are about ``offset_std`` × 2.5."""
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    tensors = init_gaussians(rng.uniform(-1, 1, (60, 3)), 0.5, 0.3, torch.device("cpu"))
    add_rgb_sh(tensors, 0)
    surface = GaussianSet({**tensors, "thermal": torch.zeros(60, 1)})
    smoke = make_smoke(rng.uniform(-4, 4, (500, 3)), 0.3, 1.0, 0.3, rng, torch.device("cpu"))
    net = DeformNetwork(DeformConfig(depth=3, width=32, skip_layer=1, predict_rotation_scale=True), 2.5,
                        torch.device("cpu"))
    torch.nn.init.normal_(net.head.weight, std=offset_std)
    model = SceneModel(surface, smoke, net, False, torch.zeros(3), 0)
    viewmat = np.eye(4)
    viewmat[2, 3] = 6.0
    K = np.array([[80.0, 0, 24], [0, 80.0, 18], [0, 0, 1]])
    return model, make_view(viewmat, K, 48, 36, 0.4, torch.device("cpu"))


def _render_and_grads(model: SceneModel, view: object, margin: float | None) -> tuple[list[torch.Tensor], list]:
    model.deform.zero_grad(set_to_none=True)
    motion = model.smoke_motion(True, False, margin) if margin is not None else None
    out = model.render_rgb(view, depth=False, motion=motion)
    (out.colors.sum() + out.subset_alphas.sum()).backward()
    return [out.colors.detach(), out.alphas.detach(), out.subset_alphas.detach()], \
        [p.grad.clone() for p in model.deform.parameters()]


def test_view_cull_renders_the_view_as_the_uncut_motion_does() -> None:
    """Smoke offsets under the margin: the cut render equals the uncut one (colours, alpha, smoke
    alpha), and so do the network's gradients, though the cut deformed only part of the smoke.
    Offsets well over a zero margin: the renders differ (smoke moving into the view is missed)."""
    model, view = _scene(0.02)
    full_offsets = model.deform(model.smoke["means"], view.time, model.center)[0].detach()
    margin = 1.5 * float(full_offsets.norm(dim=1).max())
    assert margin > 0.05
    kept = int(model.smoke_near_view(view, margin).sum())
    assert 50 < kept < model.smoke.n - 50
    (images, grads), (cut_images, cut_grads) = _render_and_grads(model, view, None), \
        _render_and_grads(model, view, margin)
    assert images[2].max() > 0.1  # the smoke shows
    for a, b in zip(images, cut_images):
        torch.testing.assert_close(b, a, rtol=0, atol=1e-6)
    for a, b in zip(grads, cut_grads):  # sums over other sets of rows: float rounding apart
        torch.testing.assert_close(b, a, rtol=0, atol=1e-5 * float(a.abs().max()))
    model, view = _scene(1.0)
    far, cut = _render_and_grads(model, view, None)[0], _render_and_grads(model, view, 0.0)[0]
    assert (far[2] - cut[2]).abs().max() > 0.05


def test_near_frustum_keeps_every_ball_that_meets_the_view() -> None:
    """Points inside the (padded) pyramid moved by less than the radius are all kept; points
    behind the near plane by more than the radius, or beyond a side plane by more than the
    radius, are dropped."""
    torch.manual_seed(4)
    viewmat = torch.eye(4, dtype=torch.float64)
    viewmat[:3, :3] = torch.linalg.qr(torch.randn(3, 3, dtype=torch.float64))[0]
    viewmat[:3, 3] = torch.tensor([0.3, -0.2, 2.0], dtype=torch.float64)
    K = torch.tensor([[60.0, 0, 20], [0, 55.0, 14], [0, 0, 1]], dtype=torch.float64)
    w, h, near = 40, 30, 0.01
    # Inside: pixels (with the pad) at depths 0.05..10, back to world, then moved up to r.
    n = 4000
    px = torch.rand(n, dtype=torch.float64) * (w + 2 * PAD_PX) - PAD_PX
    py = torch.rand(n, dtype=torch.float64) * (h + 2 * PAD_PX) - PAD_PX
    z = 0.05 + torch.rand(n, dtype=torch.float64) * 10
    cam = torch.stack([(px - K[0, 2]) / K[0, 0] * z, (py - K[1, 2]) / K[1, 1] * z, z], 1)
    world = (cam - viewmat[:3, 3]) @ viewmat[:3, :3]
    radius = torch.rand(n, dtype=torch.float64) * 0.5
    step = torch.randn(n, 3, dtype=torch.float64)
    moved = world + step / step.norm(dim=1, keepdim=True) * radius[:, None] * 0.999
    assert near_frustum(moved, radius, viewmat, K, w, h, near).all()
    behind = (torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64) * (radius[:, None] + near + 0.01)
              - viewmat[:3, 3]) @ viewmat[:3, :3]
    assert not near_frustum(behind, radius, viewmat, K, w, h, near).any()
    # Beyond the right edge: the edge's plane normal (outward) times more than the radius.
    slope = (w - K[0, 2] + PAD_PX) / K[0, 0]
    normal = torch.tensor([1.0, 0.0, -slope], dtype=torch.float64) / math.hypot(1.0, slope)
    on_edge = torch.stack([slope * z, torch.zeros(n, dtype=torch.float64), z], 1)
    outside = ((on_edge + normal * (radius[:, None] + 0.01)) - viewmat[:3, 3]) @ viewmat[:3, :3]
    assert not near_frustum(outside, radius, viewmat, K, w, h, near).any()
