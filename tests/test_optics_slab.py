"""The analytic slab against a numerically integrated transfer equation and its limits."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from generator.optics.planck import band_radiance
from generator.optics.slab import slab_radiance, transmittance


def test_transmittance_limits_without_nan_or_warnings() -> None:
    od = np.array([0.0, 1e-300, 1e-8, 1.0, 745.0, 746.0, 1e4, np.inf])
    with np.errstate(all="raise"):
        tau = transmittance(od)
    assert tau[0] == 1.0 and tau[1] == 1.0
    assert tau[2] == pytest.approx(1 - 1e-8, rel=1e-15)
    assert tau[3] == pytest.approx(np.exp(-1.0))
    assert np.all(tau[5:] == 0.0)
    assert np.all(np.diff(tau) <= 0)


def test_slab_limits() -> None:
    surface = np.array([10.0, 54.0, 300.0])
    smoke_l = band_radiance(600.0)
    np.testing.assert_array_equal(slab_radiance(surface, 0.0, 600.0), surface)
    with np.errstate(all="raise"):
        deep = slab_radiance(surface, np.array([1e4, np.inf, 800.0]), 600.0)
    np.testing.assert_allclose(deep, smoke_l, rtol=1e-15)
    # Thin slab: first-order change keeps full precision (expm1, not 1 − exp).
    thin = slab_radiance(54.0, 1e-12, 600.0)
    assert thin - 54.0 == pytest.approx(1e-12 * (smoke_l - 54.0), rel=1e-3)
    # Smoke at the surface's own brightness temperature is invisible (Kirchhoff).
    assert slab_radiance(band_radiance(320.0), 3.7, 320.0) == pytest.approx(band_radiance(320.0), rel=1e-14)


def test_matches_integrated_transfer_equation() -> None:
    """dL/ds = −σ (L − B(T)) marched through the slab by an adaptive ODE solver."""
    sigma, depth, t_smoke, l_surface = 2.3, 0.9, 450.0, 40.0
    b = float(band_radiance(t_smoke))
    sol = solve_ivp(lambda s, y: -sigma * (y - b), (0.0, depth), [l_surface], rtol=1e-11, atol=1e-12)
    assert slab_radiance(l_surface, sigma * depth, t_smoke) == pytest.approx(sol.y[0, -1], rel=1e-9)


def test_layers_compose() -> None:
    """Two layers of the same smoke equal one layer with the summed optical depth."""
    first = slab_radiance(25.0, 0.4, 380.0)
    assert slab_radiance(first, 1.1, 380.0) == pytest.approx(slab_radiance(25.0, 1.5, 380.0), rel=1e-14)


def test_broadcasting_and_validation() -> None:
    out = slab_radiance(np.full((4, 5), 50.0), np.linspace(0, 2, 5), np.full((4, 1), 400.0))
    assert out.shape == (4, 5)
    for bad in (-1e-3, np.nan):
        with pytest.raises(ValueError, match="optical_depth"):
            transmittance(bad)
        with pytest.raises(ValueError, match="optical_depth"):
            slab_radiance(10.0, bad, 300.0)
    with pytest.raises(ValueError, match="surface_radiance"):
        slab_radiance(-1.0, 0.5, 300.0)
    with pytest.raises(ValueError, match="temperature_k"):
        slab_radiance(10.0, 0.5, 0.0)
