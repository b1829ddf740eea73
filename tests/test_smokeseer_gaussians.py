"""Densification strategy, config and camera conventions."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from scenes.cameras import SceneBounds, c2w_gl_to_viewmat, sample_in_view, scene_bounds, visible_fraction
from smokeseer.config import DensifyConfig, make_config
from smokeseer.model.gaussians import DensifyStrategy, GaussianSet, knn_log_scales, logit, make_optimizer
from smokeseer.model.optim import Adam


def _set(n: int, scale: float) -> GaussianSet:
    q = torch.zeros(n, 4)
    q[:, 0] = 1
    return GaussianSet({"means": torch.arange(n * 3, dtype=torch.float32).reshape(n, 3),
                        "quats": q, "log_scales": torch.full((n, 3), math.log(scale)),
                        "opacity": torch.full((n,), logit(0.5)),
                        "color": torch.arange(n, dtype=torch.float32)[:, None]})


def _with_adam_state(g: GaussianSet) -> Adam:
    opt = make_optimizer(g, {k: 0.01 for k in g.params})
    loss = sum((p ** 2).sum() for p in g.params.values())
    loss.backward()
    opt.step()
    opt.zero_grad()
    return opt


def test_clone_split_prune_follow_3dgs_rules() -> None:
    cfg = DensifyConfig(start=0.01, stop=1.0, every=1, grad_threshold=1e-3, percent_dense=0.01,
                        opacity_reset_every=0.0, prune_opacity=0.005)
    g = _set(4, scale=0.001)
    g.params["log_scales"].data[2:] = math.log(0.5)  # rows 2, 3 are large
    g.params["opacity"].data[3] = logit(0.001)  # row 3 transparent
    opt = _with_adam_state(g)
    c = g["color"].detach().squeeze(-1).tolist()
    parent = g["log_scales"].detach()[2].exp().numpy()
    strat = DensifyStrategy(cfg, 100, ("opacity",), scene_extent=1.0)
    grad = torch.tensor([[1.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    strat.accumulate(grad, torch.tensor([3, 3, 3, 3]), width=2, height=2)
    rep = strat.step(1, g, opt, torch.Generator().manual_seed(0))
    # row 0: small + hot → cloned; row 2: large + hot → split in two and removed; row 3: pruned.
    assert rep == {"cloned": 1, "split": 1, "pruned": 2}
    assert g.n == 5  # 4 + 1 clone + 2 split children − 2 pruned (split parent, transparent row)
    assert sorted(g["color"].detach().squeeze(-1).tolist()) == sorted([c[0], c[0], c[1], c[2], c[2]])
    children = g["log_scales"].detach().exp()[g["color"].detach().squeeze(-1) == c[2]]
    assert children.shape[0] == 2
    np.testing.assert_allclose(children.numpy(), np.stack([parent, parent]) / 1.6, rtol=1e-5)
    # Adam moments follow their rows: parameters and moments stay the same length and the
    # optimizer holds the new tensors.
    for group in opt.param_groups:
        p = group["params"][0]
        assert p is g.params[group["name"]]
        st = opt.state[p]
        assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape
    # New rows start with zero moments (3DGS), surviving rows keep theirs.
    m = opt.state[g.params["color"]]["exp_avg"].squeeze(-1)
    assert (m == 0).sum() >= 3


def test_a_full_cap_grows_the_largest_gradients_with_under_cap_gradient() -> None:
    """Six hot Gaussians (rows 0-2 small, 3-5 large) and room for three under the cap. "index"
    (3DGS) clones rows 0-2 and splits none; "gradient" takes the three largest mean gradients,
    rows 5, 1 and 4: one clone and two splits. Below the cap both grow every candidate."""
    grads = torch.tensor([[1.0, 0.0], [3.0, 0.0], [2.0, 0.0], [1.5, 0.0], [4.0, 0.0], [5.0, 0.0]])
    for under_cap, cap, expect, grown in (("index", 9, {"cloned": 3, "split": 0}, [0, 1, 2]),
                                          ("gradient", 9, {"cloned": 1, "split": 2}, [1, 4, 5]),
                                          ("gradient", 100, {"cloned": 3, "split": 3}, [0, 1, 2, 3, 4, 5])):
        cfg = DensifyConfig(start=0.01, stop=1.0, every=1, grad_threshold=1e-3, opacity_reset_every=0.0,
                            max_gaussians=cap, under_cap=under_cap)
        g = _set(6, scale=0.001)
        g.params["log_scales"].data[3:] = math.log(0.5)
        opt = _with_adam_state(g)
        strat = DensifyStrategy(cfg, 100, ("opacity",), scene_extent=1.0)
        strat.accumulate(grads, torch.full((6,), 3), width=2, height=2)
        rep = strat.step(1, g, opt, torch.Generator().manual_seed(0))
        assert {k: rep[k] for k in ("cloned", "split")} == expect
        colours = [round(c) for c in g["color"].detach().squeeze(-1).tolist()]  # row numbers (one Adam step moved them)
        assert sorted(c for c in set(colours) if colours.count(c) == 2) == grown  # each grown row now twice
    with pytest.raises(ValueError, match="stage2.densify.under_cap: 'random' is not one of index, gradient"):
        make_config("full", "quick", overrides={"stage2.densify.under_cap": "random"})


def test_gradient_threshold_uses_ndc_units() -> None:
    """A pixel gradient g on a W-wide image is g·W/2 in NDC: below/above threshold flips."""
    cfg = DensifyConfig(start=0.1, stop=1.0, every=1, grad_threshold=2e-4, opacity_reset_every=0.0)
    for pixel_grad, expect in ((1.9e-4 / 50, 0), (2.1e-4 / 50, 1)):
        g = _set(1, scale=0.001)
        opt = _with_adam_state(g)
        s = DensifyStrategy(cfg, 10, ("opacity",), 1.0)
        s.accumulate(torch.tensor([[pixel_grad, 0.0]]), torch.tensor([2]), width=100, height=10)
        assert s.step(1, g, opt, torch.Generator())["cloned"] == expect


def test_oversized_gaussians_are_pruned_only_after_the_first_reset() -> None:
    """Three cold Gaussians: one small, one wider than a tenth of the extent, one with a 30 px
    screen radius. 3DGS prunes the two big ones only after its first opacity reset (here half of
    a 10-iteration stage: iteration 5), and never without resets."""
    for reset, it, expect in ((0.0, 9, 0), (0.5, 5, 0), (0.5, 6, 2)):
        cfg = DensifyConfig(start=0.1, stop=1.0, every=1, grad_threshold=1e-3, opacity_reset_every=reset)
        g = _set(3, scale=0.01)
        g.params["log_scales"].data[1] = math.log(0.2)
        opt = _with_adam_state(g)
        strat = DensifyStrategy(cfg, 10, ("opacity",), scene_extent=1.0)
        strat.accumulate(torch.zeros(3, 2), torch.tensor([2, 2, 30]), width=100, height=100)
        assert strat.step(it, g, opt, torch.Generator())["pruned"] == expect
        assert g.n == 3 - expect


def test_opacity_reset_caps_at_one_percent() -> None:
    g = _set(3, 0.01)
    opt = _with_adam_state(g)
    DensifyStrategy(DensifyConfig(), 15000, ("opacity",), 1.0).reset_opacity(g, opt)
    assert torch.sigmoid(g["opacity"]).max().item() == pytest.approx(0.01, rel=1e-4)


def test_knn_scales_match_brute_force() -> None:
    pts = np.random.default_rng(0).random((40, 3))
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    ref = np.log(np.sqrt((np.sort(d, axis=1)[:, :3] ** 2).mean(1)))
    np.testing.assert_allclose(knn_log_scales(pts)[:, 0], ref, rtol=1e-9)


def test_gl_to_cv_conversion_and_bounds() -> None:
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, 0.0, 5.0]  # OpenGL camera at z=5 looking down −z at the origin
    vm = c2w_gl_to_viewmat(c2w)
    p = vm[:3, :3] @ np.zeros(3) + vm[:3, 3]
    np.testing.assert_allclose(p, [0, 0, 5])  # origin is 5 m in front (+z in OpenCV)
    q = vm[:3, :3] @ np.array([0.0, 1.0, 0.0]) + vm[:3, 3]
    assert q[1] < 0  # world up is image up (−y in OpenCV)
    vms, ks = [], []
    for a in np.linspace(0, 2 * np.pi, 8, endpoint=False):
        eye = np.array([5 * np.cos(a), 5 * np.sin(a), 0.0])
        f = -eye / 5
        r = np.cross(f, [0, 0, 1.0])
        u = np.cross(r, f)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = r, u, -f, eye
        vms.append(c2w_gl_to_viewmat(m))
        ks.append(np.array([[50.0, 0, 32], [0, 50, 24], [0, 0, 1]]))
    b = scene_bounds(np.stack(vms), np.stack(ks), np.full(8, 64))
    np.testing.assert_allclose(b.center, 0.0, atol=1e-9)
    assert b.half_size == pytest.approx(5 * 32 / 50)
    assert b.extent == pytest.approx(1.1 * 5)


def _one_camera_at(z: float) -> tuple[np.ndarray, np.ndarray]:
    """An OpenGL camera at (0, 0, z) looking down −z, 64×48 px, focal 50 px."""
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, 0.0, z]
    return c2w_gl_to_viewmat(c2w)[None], np.array([[[50.0, 0, 32], [0, 50, 24], [0, 0, 1]]])


def test_random_start_points_are_seen_and_the_ones_that_cannot_be_are_counted() -> None:
    vm, k = _one_camera_at(5.0)
    w, h = np.array([64]), np.array([48])
    # A box the camera sees a part of: every point kept is in its image, none unseen.
    seen = sample_in_view(SceneBounds(np.zeros(3), 2.0, 2.0), 500, vm, k, w, h, np.random.default_rng(0))
    assert seen.points.shape == (500, 3) and seen.unseen == 0
    assert (visible_fraction(seen.points, vm, k, w, h) == 1.0).all()
    # A box behind the camera: no candidate can be seen, so all are drawn unchecked and counted.
    behind = sample_in_view(SceneBounds(np.array([0.0, 0.0, 20.0]), 1.0, 1.0), 50, vm, k, w, h,
                            np.random.default_rng(0))
    assert behind.points.shape == (50, 3) and behind.unseen == 50
    assert (np.abs(behind.points - [0.0, 0.0, 20.0]) <= 1.0).all()


def test_config_profiles_overrides_and_errors() -> None:
    paper = make_config("full", "paper")
    assert (paper.stage2.iterations, paper.stage3.iterations) == (15000, 15000)
    assert (paper.stage2.deform_warmup, paper.stage3.deform_warmup) == (0.2, 0.2)
    lw = paper.loss
    assert (lw.render, lw.smoke_alpha, lw.smoke_color, lw.mono, lw.depth, lw.mask) == (1.0, 0.1, 0.05, 0.1, 2.0, 0.5)
    quick = make_config("no-mask", "quick", overrides={"stage3.iterations": "7", "progress": "false"})
    assert quick.stage3.iterations == 7 and quick.progress is False
    assert quick.sha256() != make_config("no-mask", "quick").sha256()
    with pytest.raises(ValueError, match="mode"):
        make_config("bogus")
    with pytest.raises(ValueError, match="overrides.*nope"):
        make_config(overrides={"stage3.nope": 1})
    with pytest.raises(ValueError, match="stage2.iterations"):
        make_config(overrides={"stage2.iterations": -1})
    with pytest.raises(ValueError, match="loss.mask_alpha_floor"):
        make_config(overrides={"loss.mask_alpha_floor": 0.0})
    with pytest.raises(ValueError, match=r"stage3.surface_densify.stop: a fraction of the stage's iterations"):
        make_config(overrides={"stage3.surface_densify.stop": 2400})
    with pytest.raises(ValueError, match="stage2.densify.start: must not be after stage2.densify.stop"):
        make_config(overrides={"stage2.densify.start": 0.9})
    with pytest.raises(ValueError, match="stage3.deform_warmup: a fraction"):
        make_config(overrides={"stage3.deform_warmup": 500})
