"""Stage 3's two-surface start: how much of the RGB Stage 2 it keeps by the haze-line trust, carving
RGB Gaussians in front of the thermal surface, and the join."""
from __future__ import annotations

import numpy as np
import torch

from smokeseer.model.gaussians import GaussianSet
from smokeseer.model.scene import add_rgb_sh
from smokeseer.stage1.haze_lines import SmokeColourEstimate
from smokeseer.train.surface_union import (SHARE_FLOOR, carve_in_front, fade, in_holes, smoky_share,
                                           surface_start, union_surface)

W, H, F = 40, 30, 20.0


def _camera(shift_x: float) -> np.ndarray:
    """World-to-camera of a camera at (shift_x, 0, 0) looking down +z (OpenCV axes)."""
    m = np.eye(4)
    m[0, 3] = -shift_x
    return m


def _cameras(shifts: list[float]) -> tuple[np.ndarray, np.ndarray]:
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1.0]])
    return np.stack([_camera(s) for s in shifts]), np.stack([K] * len(shifts))


def _wall(n: int, depth: float, valid_cols: int = W) -> tuple[np.ndarray, np.ndarray]:
    maps = np.full((n, H, W), depth)
    valid = np.zeros((n, H, W), dtype=bool)
    valid[:, :, :valid_cols] = True
    return maps, valid


def test_points_in_front_of_the_wall_are_carved_and_the_rest_kept() -> None:
    cameras = _cameras([0.0, 0.1, -0.1])
    means = np.array([[0.0, 0.0, 1.0],     # half-way to the wall: smoke taken for surface
                          [0.0, 0.0, 1.95],    # on the wall, within the 5 % tolerance
                          [0.0, 0.0, 1.85],    # 7.5 % in front: carved
                          [0.0, 0.0, 3.0],     # behind the wall (hidden), kept
                          [50.0, 0.0, 1.0],    # outside every view: nothing checks it
                          [0.0, 0.0, -1.0]])   # behind the cameras
    c = carve_in_front(means, *_wall(3, 2.0), *cameras, 0.05)
    assert c.keep.tolist() == [False, True, False, True, True, True]
    assert c.seen.tolist() == [3, 3, 3, 3, 0, 0]
    assert c.in_front.tolist() == [3, 0, 3, 0, 0, 0]


def test_the_smoky_share_in_front_weighs_each_view_in_front_by_its_mask() -> None:
    """carve_by=depth-and-smoke's input: a point in front of the wall in all three views, on smoke
    (mask 1, 1, 0.5), gets 2.5 / 3; one on the wall or behind it gets 0 whatever the masks say;
    without masks every share is 0."""
    cameras = _cameras([0.0, 0.1, -0.1])
    means = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.95], [0.0, 0.0, 3.0]])
    masks = np.ones((3, H, W))
    masks[2] = 0.5
    c = carve_in_front(means, *_wall(3, 2.0), *cameras, 0.05, masks)
    np.testing.assert_allclose(c.smoky_in_front, [2.5 / 3, 0.0, 0.0])
    assert c.keep.tolist() == [False, True, True]
    assert carve_in_front(means, *_wall(3, 2.0), *cameras, 0.05).smoky_in_front.tolist() == [0.0, 0.0, 0.0]


def test_a_minority_of_views_in_front_does_not_carve() -> None:
    """In front of the surface in one view of three (hidden behind it in the others): kept. On
    pixels without valid thermal depth: nothing checks it, kept."""
    cameras = _cameras([0.0, 0.0, 0.0])
    maps, valid = _wall(3, 2.0)
    maps[1:] = 0.5  # two views' surface nearer than the point: it is behind it there
    means = np.array([[0.0, 0.0, 1.0]])
    c = carve_in_front(means, maps, valid, *cameras, 0.05)
    assert c.seen.tolist() == [3] and c.in_front.tolist() == [1] and c.keep.tolist() == [True]
    c = carve_in_front(means, *_wall(3, 2.0, valid_cols=W // 2), *cameras, 0.05)  # centre column is W/2: invalid
    assert c.seen.tolist() == [0] and c.keep.tolist() == [True]


def test_thermal_gaussians_join_only_where_the_rgb_surface_has_holes() -> None:
    """A point over an opaque RGB pixel in two of three views is covered (left out at share 0.5,
    kept at 0.7); one over a hole in every view, and one no view sees, are kept."""
    cameras = _cameras([0.0, 0.0, 0.0])
    _, opaque = _wall(3, 2.0, valid_cols=W // 2 + 1)  # columns up to the centre one are opaque
    opaque[2] = False
    means = np.array([[0.0, 0.0, 1.0],     # centre column: opaque in views 0 and 1
                      [0.5, 0.0, 1.0],     # right half: a hole everywhere
                      [50.0, 0.0, 1.0]])   # outside every view
    assert in_holes(means, opaque, *cameras, 0.5).tolist() == [False, True, True]
    assert in_holes(means, opaque, *cameras, 0.7).tolist() == [True, True, True]
    assert in_holes(means, opaque, *cameras, 1.0).all()


def test_union_with_a_thermal_subset_takes_thermal_values_from_every_thermal_gaussian() -> None:
    """The RGB Gaussians' thermal value comes from the nearest of all thermal Gaussians, even one
    left out of the joined surface."""
    thermal = _set([[0.0, 0, 0], [10.0, 0, 0]], {"thermal": torch.tensor([[-2.0], [3.0]])})
    rgb_t: dict[str, torch.Tensor] = {"means": torch.tensor([[9.0, 0, 0]])}
    add_rgb_sh(rgb_t, 1, torch.tensor([[0.1, 0.9, 0.1]]))
    rgb = _set(rgb_t.pop("means").tolist(), rgb_t)
    joined = union_surface(thermal, rgb, torch.tensor([True]), torch.tensor([True, False]), 1)
    assert joined.n == 2
    assert torch.equal(joined["thermal"].flatten(), torch.tensor([-2.0, 3.0]))


def _set(points: list[list[float]], extra: dict[str, torch.Tensor]) -> GaussianSet:
    n = len(points)
    t = {"means": torch.tensor(points), "quats": torch.tensor([[1.0, 0, 0, 0]] * n),
         "log_scales": torch.zeros(n, 3), "opacity": torch.zeros(n, 1)}
    t.update(extra)
    return GaussianSet(t)


def test_union_takes_each_colour_from_the_nearest_gaussian_of_the_other_set() -> None:
    thermal = _set([[0.0, 0, 0], [10.0, 0, 0]], {"thermal": torch.tensor([[-2.0], [3.0]])})
    rgb_t: dict[str, torch.Tensor] = {"means": torch.tensor([[0.5, 0, 0], [9.0, 0, 0], [4.0, 0, 0]])}
    add_rgb_sh(rgb_t, 1, torch.tensor([[0.9, 0.1, 0.1], [0.1, 0.9, 0.1], [0.1, 0.1, 0.9]]))
    rgb_t["sh_rest"] += 0.3
    rgb = _set(rgb_t.pop("means").tolist(), rgb_t)
    joined = union_surface(thermal, rgb, torch.tensor([True, True, False]), torch.ones(2, dtype=torch.bool), 1)
    assert joined.n == 4
    assert torch.equal(joined["means"][:2], thermal["means"]) and torch.equal(joined["means"][2:], rgb["means"][:2])
    assert torch.equal(joined["thermal"].flatten(), torch.tensor([-2.0, 3.0, -2.0, 3.0]))
    assert torch.equal(joined["sh_dc"][0], rgb["sh_dc"][0]) and torch.equal(joined["sh_dc"][1], rgb["sh_dc"][1])
    assert torch.equal(joined["sh_rest"][:2], torch.zeros(2, 3, 3)) and torch.all(joined["sh_rest"][2:] == 0.3)
    none_kept = union_surface(thermal, rgb, torch.zeros(3, dtype=torch.bool), torch.ones(2, dtype=torch.bool), 1)
    assert none_kept.n == 2 and torch.allclose(none_kept["sh_dc"], _grey_dc(2))


def _grey_dc(n: int) -> torch.Tensor:
    t = {"means": torch.zeros(n, 3)}
    add_rgb_sh(t, 1)
    return t["sh_dc"]


def test_the_rgb_share_of_the_start_is_one_minus_the_surface_trust() -> None:
    """The start follows the estimate's surface trust, never the colour's (a colour at trust 0.5
    with surface trust 1 starts from the thermal Stage 2 alone)."""
    dark = np.array([0.2, 0.2, 0.2])
    shares = [surface_start(SmokeColourEstimate(dark, 500, 900, 0.8, trust=0.0, surface_trust=t), True)[0]
              for t in (0.0, 0.25, 1.0)]
    assert shares == [1.0, 0.75, 0.0]
    assert surface_start(None, True)[0] == 1.0 and surface_start(SmokeColourEstimate(None, 12, 900), True)[0] == 1.0
    held = SmokeColourEstimate(dark, 500, 900, 0.8, trust=0.5, surface_trust=1.0)
    assert surface_start(held, False)[0] == 1.0  # no smoke
    assert "thermal Stage 2 alone" in surface_start(held, True)[1]


def test_fade_scales_every_opacity_and_nothing_else() -> None:
    rng = np.random.default_rng(0)
    logits = torch.as_tensor(np.concatenate([rng.normal(0, 3, 50), [-30.0, 30.0]]), dtype=torch.float32)
    g = GaussianSet({"means": torch.as_tensor(rng.normal(size=(52, 3)), dtype=torch.float32),
                     "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(52, 1), "log_scales": torch.zeros(52, 3),
                     "opacity": logits})
    for share in (0.75, 1e-3):
        faded = fade(g, share)
        opacity = torch.sigmoid(faded["opacity"])
        assert torch.isfinite(faded["opacity"]).all()
        torch.testing.assert_close(opacity, share * torch.sigmoid(logits), rtol=1e-5, atol=1e-7)
        torch.testing.assert_close(faded["means"], g["means"], rtol=0, atol=0)
    assert fade(g, 1.0) is g


def test_fade_per_gaussian_scales_each_opacity_by_its_own_share() -> None:
    """One share per Gaussian, as carve_by=depth-and-smoke gives: each opacity scaled by its own, a share of 0
    held at the floor with a finite logit, a share of 1 leaving that opacity exactly."""
    logits = torch.tensor([-2.0, 0.0, 3.0, 30.0, 1.0])
    g = GaussianSet({"means": torch.zeros(5, 3), "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(5, 1),
                     "log_scales": torch.zeros(5, 3), "opacity": logits})
    shares = np.array([0.5, 0.1, 1.0, 0.0, 0.9])
    faded = fade(g, shares)
    assert torch.isfinite(faded["opacity"]).all()
    expected = torch.as_tensor(np.maximum(shares, SHARE_FLOOR), dtype=torch.float32) * torch.sigmoid(logits)
    torch.testing.assert_close(torch.sigmoid(faded["opacity"]), expected, rtol=1e-5, atol=1e-7)
    assert fade(g, np.ones(5)) is g


def test_smoky_share_is_the_mean_mask_of_every_view_a_centre_lands_in() -> None:
    """The thermal gate's share (stage3.thermal_surface_grad=smoky-views): a soft mask counts as
    its value, and with no occlusion test a point behind the wall counts the wall's masks; a point
    no view sees gets 1 (only the thermal frames speak of it)."""
    cameras = _cameras([0.0, 0.0, 0.0])
    masks = np.zeros((3, H, W))
    masks[:2, :, : W // 2 + 1] = 1.0
    masks[:, :, W // 2 + 5:] = 0.25
    means = np.array([[0.0, 0.0, 2.0],      # centre column: masked in views 0 and 1
                      [0.4, 0.0, 2.0],      # column 24: no mask
                      [0.9, 0.0, 2.0],      # column 29: the soft mask
                      [0.0, 0.0, 3.0],      # behind the wall's centre: the wall's masks
                      [50.0, 0.0, 2.0]])    # outside every view
    share = smoky_share(means, masks, *cameras)
    np.testing.assert_allclose(share, [2 / 3, 0.0, 0.25, 2 / 3, 1.0])
