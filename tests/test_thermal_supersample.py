"""stage3.thermal_supersample: a thermal pixel drawn as sub-pixels and averaged integrates its area.

The reference is independent of the rasterizer: the integral of a 2D Gaussian over each pixel's
square, from the normal CDF (scipy). The rasterizer adds a fixed low-pass of EPS2D px² to every
projected covariance in the pixels it draws, so a render with s sub-pixels a side sees a Gaussian of
variance σ² + EPS2D/s² in sensor pixels; with that variance the averaged render must match the
pixel integrals, and the footprint it gives a Gaussian far smaller than a pixel must approach the
true one, where one sample at the pixel centre inflates it several times.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.stats import norm

from smokeseer.config import MAX_THERMAL_SUPERSAMPLE, make_config
from smokeseer.model.scene import Placed, make_view, render
from smokeseer.raster.output import box_filtered
from smokeseer.raster.projection import EPS2D

WIDTH, HEIGHT, FOCAL, DEPTH = 14, 12, 10.0, 2.0
CENTRE = (6.3, 5.7)  # the Gaussian's image position in sensor pixels: off every pixel centre
OPACITY = 0.5


def _render(sigma_px: float, factor: int) -> np.ndarray:
    """Alpha of one isotropic Gaussian on the optical axis, whose projected std is ``sigma_px``
    sensor pixels (the Jacobian is exactly diag(f/z) there), rendered with ``factor`` sub-pixels a
    side and box-filtered back to the sensor's pixels."""
    K = np.array([[FOCAL, 0.0, CENTRE[0]], [0.0, FOCAL, CENTRE[1]], [0.0, 0.0, 1.0]])
    view = make_view(np.eye(4), K, WIDTH, HEIGHT, 0.0, torch.device("cpu")).supersampled(factor)
    assert (view.width, view.height) == (WIDTH * factor, HEIGHT * factor)
    sigma_world = sigma_px * DEPTH / FOCAL
    placed = Placed(torch.tensor([[0.0, 0.0, DEPTH]]), torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
                    torch.full((1, 3), math.log(sigma_world)))
    out = box_filtered(render(view, [(placed, torch.tensor([OPACITY]), torch.ones(1, 1))], None, None), factor)
    assert out.colors.shape == (1, HEIGHT, WIDTH, 1)
    return out.alphas[0, ..., 0].numpy()


def _pixel_integrals(sigma: float) -> np.ndarray:
    """OPACITY × the mean over each sensor pixel's unit square of exp(−r²/2σ²) around CENTRE."""
    def along(n: int, c: float) -> np.ndarray:
        edges = np.arange(n + 1, dtype=np.float64)
        return np.diff(norm.cdf((edges - c) / sigma)) * sigma * math.sqrt(2 * math.pi)
    return OPACITY * np.outer(along(HEIGHT, CENTRE[1]), along(WIDTH, CENTRE[0]))


def test_the_averaged_sub_pixels_give_each_pixel_the_integral_over_its_area() -> None:
    """σ = 1 px: every pixel within 2σ of the centre (past that the rasterizer drops alphas under
    1/255) matches the integral of the Gaussian the sub-pixels see, with the midpoint rule's error,
    which falls as 1/s²: a sub-pixel grid shifted or scaled against the pixel would leave an error
    that does not fall that way."""
    sigma = 1.0
    near = np.hypot(*np.meshgrid(np.arange(WIDTH) + 0.5 - CENTRE[0], np.arange(HEIGHT) + 0.5 - CENTRE[1])) < 2 * sigma
    error = {s: np.abs(_render(sigma, s) - _pixel_integrals(math.sqrt(sigma**2 + EPS2D / s**2)))[near].max()
             for s in (1, 2, 4)}
    assert error[4] < 3e-3
    for s in (2, 4):
        assert error[s] * s**2 == pytest.approx(error[1], rel=0.2)


def test_a_gaussian_smaller_than_a_pixel_keeps_its_footprint() -> None:
    """σ = 0.35 px, as a surface Gaussian sized for RGB pixels 2.5 times finer: its summed alpha
    should be OPACITY · 2πσ². One sample per pixel dilates it by EPS2D px² and sums to more than
    three times that; three and four sub-pixels a side bring the excess under a third and a fifth."""
    sigma = 0.35
    truth = OPACITY * 2 * math.pi * sigma**2
    excess = {s: _render(sigma, s).sum() / truth - 1 for s in (1, 2, 3, 4)}
    assert excess[1] > 2.0
    assert excess[1] > excess[2] > excess[3] > excess[4] > 0
    assert excess[3] < 0.33 and excess[4] < 0.2


def test_one_sub_pixel_is_the_plain_render() -> None:
    K = np.array([[FOCAL, 0.0, CENTRE[0]], [0.0, FOCAL, CENTRE[1]], [0.0, 0.0, 1.0]])
    view = make_view(np.eye(4), K, WIDTH, HEIGHT, 0.0, torch.device("cpu"))
    assert view.supersampled(1) is view
    assert np.array_equal(_render(0.5, 1), _render(0.5, 1))


@pytest.mark.parametrize("value", [0, MAX_THERMAL_SUPERSAMPLE + 1])
def test_a_supersample_outside_its_range_is_refused_by_name(value: int) -> None:
    with pytest.raises(ValueError, match=r"^stage3\.thermal_supersample: must be 1 to"):
        make_config("full", "standard", 0, {"stage3.thermal_supersample": value})
