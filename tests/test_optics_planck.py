"""Band radiance against independent references: a closed-form series, Stefan-Boltzmann,
scipy's adaptive quadrature, published values, finite differences."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.constants
from colour.colorimetry import planck_law
from colour.colorimetry.blackbody import CONSTANT_C1, CONSTANT_C2
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from generator.optics.planck import (
    LWIR_BAND_M,
    PlanckQuadrature,
    band_radiance,
    band_radiance_derivative,
    brightness_temperature,
    radiance_table,
)


def _tail_series(a: float) -> float:
    """∫_a^∞ u³/(eᵘ−1) du = Σₙ e^(−na)(a³/n + 3a²/n² + 6a/n³ + 6/n⁴) (Widger & Woodall 1976)."""
    if np.isinf(a):
        return 0.0
    n = np.arange(1, 20001, dtype=np.float64)
    return float(np.sum(np.exp(-n * a) * (a**3 / n + 3 * a**2 / n**2 + 6 * a / n**3 + 6 / n**4)))


def _series_band(t: float, band: tuple[float, float] = LWIR_BAND_M) -> float:
    lo, hi = band
    u_lo = 0.0 if np.isinf(hi) else CONSTANT_C2 / (hi * t)
    u_hi = np.inf if lo == 0 else CONSTANT_C2 / (lo * t)
    scale = CONSTANT_C1 / np.pi * (t / CONSTANT_C2) ** 4
    return scale * (_tail_series(u_lo) - _tail_series(u_hi))


@pytest.mark.parametrize(
    ("t", "expected"),
    [(273.0, 35.05), (293.0, 49.25), (300.0, 54.93), (310.0, 63.69), (373.0, 136.6),
     (600.0, 616.6), (1000.0, 1924.0), (50.0, 2.07e-7)],
)
def test_knowledge_values(t: float, expected: float) -> None:
    assert band_radiance(t) == pytest.approx(expected, rel=5e-3)


def test_matches_closed_form_series_over_the_whole_range() -> None:
    temps = np.array([3.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 300.0, 500.0, 1000.0, 2000.0, 5000.0])
    got = band_radiance(temps)
    ref = np.array([_series_band(t) for t in temps])
    np.testing.assert_allclose(got, ref, rtol=1e-10)


def test_matches_scipy_adaptive_quadrature_in_wavelength() -> None:
    for t in (250.0, 300.0, 800.0):
        ref, _ = quad(lambda lam: float(planck_law(lam, t)), *LWIR_BAND_M, epsabs=0, epsrel=1e-12)
        assert band_radiance(t) == pytest.approx(ref, rel=1e-9)


@pytest.mark.parametrize("t", [1.0, 30.0, 300.0, 1000.0, 5000.0])
def test_full_band_is_stefan_boltzmann(t: float) -> None:
    full = band_radiance(t, (0.0, np.inf))
    codata = scipy.constants.Stefan_Boltzmann * t**4 / np.pi
    assert full == pytest.approx(codata, rel=1e-4)
    # colour's constants (c2 = 1.4388e-2, ITS-90) give σ 6.5e-5 below CODATA; against the σ
    # implied by those same constants the quadrature itself is exact to ~1e-12.
    implied = CONSTANT_C1 * np.pi**4 / (15 * CONSTANT_C2**4) * t**4 / np.pi
    assert full == pytest.approx(implied, rel=1e-11)


def test_band_fraction_matches_knowledge() -> None:
    sigma = scipy.constants.Stefan_Boltzmann
    assert band_radiance(300.0) / (sigma * 300.0**4 / np.pi) == pytest.approx(0.376, abs=1e-3)
    assert band_radiance(1000.0) / (sigma * 1000.0**4 / np.pi) == pytest.approx(0.107, abs=1e-3)


def test_monotone_and_finite_from_1_to_5000_k_without_warnings() -> None:
    temps = np.concatenate([np.linspace(1.0, 3.0, 201)[:-1], np.geomspace(3.0, 5000.0, 4000)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lum = band_radiance(temps)
        slope = band_radiance_derivative(temps)
        full = band_radiance(temps, (0.0, np.inf))
    for arr in (lum, slope, full):
        assert np.all(np.isfinite(arr)) and np.all(arr >= 0)
    assert np.all(np.diff(lum) >= 0)
    positive = lum > 0
    assert np.all(np.diff(lum[positive]) > 0)
    assert np.all(slope[positive & (lum > 1e-280)] > 0)
    assert lum[0] == 0.0  # 1 K: the true value (~1e-440) is below the smallest double


def test_derivative_matches_central_differences() -> None:
    for t in (20.0, 120.0, 300.0, 1000.0, 4000.0):
        h = 1e-4 * t
        fd = (band_radiance(t + h) - band_radiance(t - h)) / (2 * h)
        assert band_radiance_derivative(t) == pytest.approx(fd, rel=1e-7)
    assert band_radiance_derivative(300.0) == pytest.approx(0.84, abs=0.01)
    full = band_radiance_derivative(400.0, (0.0, np.inf))
    implied = 4 * CONSTANT_C1 * np.pi**4 / (15 * CONSTANT_C2**4) * 400.0**3 / np.pi
    assert full == pytest.approx(implied, rel=1e-10)


def test_round_trip_on_a_grid_and_band_variants() -> None:
    temps = np.geomspace(2.0, 5000.0, 500)
    for band in (LWIR_BAND_M, (3e-6, 5e-6), (0.0, np.inf)):
        lum = band_radiance(temps, band)
        normal = lum > 1e-290  # MWIR radiance underflows below ~3 K; the inverse then says 0 K
        back = brightness_temperature(lum, band)
        np.testing.assert_allclose(back[normal], temps[normal], rtol=1e-10)
        assert np.all(back[lum == 0] == 0)


@settings(max_examples=60, deadline=None)
@given(st.floats(min_value=2.0, max_value=5000.0, allow_nan=False))
def test_round_trip_property(t: float) -> None:
    assert float(brightness_temperature(band_radiance(t))) == pytest.approx(t, rel=1e-6)


def test_brightness_temperature_edges() -> None:
    assert float(brightness_temperature(0.0)) == 0.0
    assert brightness_temperature(np.array([[54.9294]])).shape == (1, 1)
    with pytest.raises(ValueError, match="radiance"):
        brightness_temperature(-1.0)
    with pytest.raises(ValueError, match="radiance"):
        brightness_temperature(np.nan)
    with pytest.raises(ValueError, match="radiance"):
        brightness_temperature(1e300)


@pytest.mark.parametrize("bad", [0.0, -5.0, np.nan, np.inf])
def test_invalid_temperature_raises(bad: float) -> None:
    with pytest.raises(ValueError, match="temperature_k"):
        band_radiance(bad)
    with pytest.raises(ValueError, match="temperature_k"):
        band_radiance_derivative(np.array([300.0, bad]))


@pytest.mark.parametrize("band", [(14e-6, 8e-6), (-1e-6, 8e-6), (8e-6, 8e-6), (np.nan, 1e-5), (1e-5,)])
def test_invalid_band_raises(band: tuple[float, ...]) -> None:
    with pytest.raises(ValueError, match="band_m"):
        band_radiance(300.0, band)  # type: ignore[arg-type]


def test_quadrature_converges_with_nodes() -> None:
    ref = _series_band(40.0)
    errors = [abs(band_radiance(40.0, quadrature=PlanckQuadrature(k)) / ref - 1) for k in (2, 4, 8)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-11
    with pytest.raises(ValueError, match="nodes_per_panel"):
        PlanckQuadrature(0)


def test_radiance_table_interpolation_error_below_tolerance() -> None:
    for t_min, t_max, tol in ((250.0, 2000.0, 1e-3), (20.0, 400.0, 1e-3), (280.0, 330.0, 1e-4)):
        table = radiance_table(t_min, t_max, rel_tol=tol)
        t = table.temperatures_k
        assert t[0] == t_min and t[-1] == t_max
        dense = np.concatenate([np.linspace(a, b, 41) for a, b in zip(t[:-1], t[1:])])
        exact = band_radiance(dense)
        err = np.abs(table.radiance_at(dense) / exact - 1)
        assert err.max() < tol
        np.testing.assert_allclose(table.radiance, band_radiance(t), rtol=1e-14)
        assert np.all(np.abs(table.temperature_at(table.radiance_at(dense)) - dense) < 1e-9 * dense)
    with pytest.raises(ValueError, match="t_min_k"):
        radiance_table(300.0, 200.0)
