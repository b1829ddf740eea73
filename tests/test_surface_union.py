"""Stage 3's two-surface start: carving RGB Gaussians in front of the thermal surface, and the join."""
from __future__ import annotations

import numpy as np
import torch

from smokeseer.model.gaussians import GaussianSet
from smokeseer.model.scene import add_rgb_sh, make_view
from smokeseer.train.surface_union import carve_in_front, in_holes, union_surface

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
    joined = union_surface(thermal, rgb, torch.tensor([True]), 1, thermal_keep=torch.tensor([True, False]))
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
    joined = union_surface(thermal, rgb, torch.tensor([True, True, False]), 1)
    assert joined.n == 4
    assert torch.equal(joined["means"][:2], thermal["means"]) and torch.equal(joined["means"][2:], rgb["means"][:2])
    assert torch.equal(joined["thermal"].flatten(), torch.tensor([-2.0, 3.0, -2.0, 3.0]))
    assert torch.equal(joined["sh_dc"][0], rgb["sh_dc"][0]) and torch.equal(joined["sh_dc"][1], rgb["sh_dc"][1])
    assert torch.equal(joined["sh_rest"][:2], torch.zeros(2, 3, 3)) and torch.all(joined["sh_rest"][2:] == 0.3)
    none_kept = union_surface(thermal, rgb, torch.zeros(3, dtype=torch.bool), 1)
    assert none_kept.n == 2 and torch.allclose(none_kept["sh_dc"], _grey_dc(2))


def _grey_dc(n: int) -> torch.Tensor:
    t = {"means": torch.zeros(n, 3)}
    add_rgb_sh(t, 1)
    return t["sh_dc"]


# --- the thermal forward model: finer render, box filter to the sensor pixel -----------------

def _one_gaussian_alpha_sum(sigma_px: float, factor: int) -> float:
    """Summed alpha over an 80×60 frame of one isotropic Gaussian of ``sigma_px`` sensor pixels
    at opacity 0.5, rendered ``factor`` times finer and box-filtered (in sensor pixels²)."""
    from smokeseer.model.scene import Placed, box_filter, finer_view, render

    z = 2.0
    K = np.array([[F, 0, 40.0], [0, F, 30.0], [0, 0, 1.0]])
    view = make_view(np.eye(4), K, 80, 60, 0.0, torch.device("cpu"))
    scale = sigma_px * z / F
    placed = Placed(torch.tensor([[0.013, -0.021, z]]), torch.tensor([[1.0, 0, 0, 0]]),
                    torch.full((1, 3), float(np.log(scale))))
    one = torch.ones(1, 1)
    if factor > 1:
        view = finer_view(view, factor)
    out = render(view, [(placed, torch.full((1,), 0.5), one)], None, None)
    colours = out.colors if factor == 1 else box_filter(out.colors, factor)
    assert colours.shape == (1, 60, 80, 1)
    return float(colours.sum())


def test_a_finer_thermal_render_keeps_a_small_gaussians_footprint() -> None:
    """A Gaussian of 0.3 sensor pixels covers o·2πσ² = 0.283 px² of alpha. At the sensor's
    pixels the rasterizer's 0.3 px² dilation draws it four times that; rendered 4× finer and
    box-filtered it is within 25 %. A large Gaussian is the same either way (the filter keeps
    its mass)."""
    exact = 0.5 * 2 * np.pi * 0.3**2
    assert _one_gaussian_alpha_sum(0.3, 1) > 3.5 * exact
    assert abs(_one_gaussian_alpha_sum(0.3, 4) - exact) < 0.25 * exact
    big = 0.5 * 2 * np.pi * 4.0**2
    assert abs(_one_gaussian_alpha_sum(4.0, 1) - big) < 0.12 * big
    assert abs(_one_gaussian_alpha_sum(4.0, 3) - big) < 0.05 * big


def test_the_thermal_gate_stops_the_thermal_gradient_at_the_rgb_gaussians() -> None:
    """With the gate, the thermal render's gradient reaches the geometry and opacity of the
    thermal Gaussians only; the RGB ones still get it on their thermal value. Without it, both."""
    from smokeseer.model.scene import SceneModel

    thermal = _set([[-0.2, 0.0, 2.0]], {"thermal": torch.tensor([[0.5]]), "opacity": torch.zeros(1)})
    rgb_t: dict[str, torch.Tensor] = {"means": torch.tensor([[0.2, 0.0, 2.0]])}
    add_rgb_sh(rgb_t, 1, torch.tensor([[0.5, 0.5, 0.5]]))
    rgb = _set(rgb_t.pop("means").tolist(), {**rgb_t, "opacity": torch.zeros(1)})
    view = make_view(_camera(0.0), _cameras([0.0])[1][0], W, H, 0.0, torch.device("cpu"))
    grads = {}
    for gate in (False, True):
        joined = union_surface(thermal, rgb, torch.tensor([True]), 1, gate=gate)
        with torch.no_grad():
            joined["log_scales"].fill_(-2.0)
        model = SceneModel(joined, None, None, True, torch.zeros(3), 1)
        model.render_thermal(view).colors.sum().backward()
        grads[gate] = {k: joined[k].grad.clone() for k in ("means", "opacity", "log_scales", "thermal")}
    for k in ("means", "opacity", "log_scales"):
        assert grads[False][k][1].abs().sum() > 0 and torch.equal(grads[True][k][1], torch.zeros_like(grads[True][k][1]))
        assert torch.equal(grads[True][k][0], grads[False][k][0])
    assert torch.equal(grads[True]["thermal"], grads[False]["thermal"]) and grads[True]["thermal"][1].abs() > 0
