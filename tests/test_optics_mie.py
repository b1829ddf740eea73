"""Mie efficiencies against published tables and asymptotes; size averaging against an
independent quadrature; band optics against their defining properties."""

from __future__ import annotations

import json
import warnings

import colour
import numpy as np
import pytest
from colour.utilities import ColourRuntimeWarning

from generator.optics.mie import (
    ORGANIC_SMOKE,
    SOOT,
    ParticlePopulation,
    SmokeOptics,
    efficiencies,
    smoke_optics,
    spectral_coefficients,
)
from generator.optics.refractive_index import SOOT as SOOT_INDEX
from generator.optics.refractive_index import WATER_SOLUBLE


def test_bohren_huffman_appendix_sphere() -> None:
    # Bohren & Huffman (1983), Appendix A (BHMIE): m = 1.55, r = 0.525 µm, λ = 0.6328 µm.
    x = 2 * np.pi * 0.525 / 0.6328
    qext, qsca, g = efficiencies(1.55, x)
    assert float(qext) == pytest.approx(3.10543, abs=1e-5)
    assert float(qsca) == pytest.approx(3.10543, abs=1e-5)
    assert float(g) == pytest.approx(0.63314, abs=1e-5)


@pytest.mark.parametrize(
    ("m", "x", "qext", "qsca", "g"),
    [
        # Wiscombe (1979, NCAR/TN-140+STR), MIEV0 test cases; m written as n + ik.
        (0.75 + 0.0j, 10.0, 2.232265, 2.232265, 0.896473),
        (1.5 + 1.0j, 1.0, 2.336321, 0.6634538, 0.192136),
        (1.5 + 1.0j, 100.0, 2.097502, 1.283697, 0.850252),
        (1.5 + 1.0j, 10000.0, 2.004368, 1.236575, 0.846309),
        (10.0 + 10.0j, 1.0, None, 2.049405, -0.110664),
    ],
)
def test_wiscombe_published_cases(m: complex, x: float, qext: float | None, qsca: float, g: float) -> None:
    got_ext, got_sca, got_g = efficiencies(m, x)
    if qext is not None:
        assert float(got_ext) == pytest.approx(qext, abs=2e-6)
    assert float(got_sca) == pytest.approx(qsca, abs=2e-6)
    assert float(got_g) == pytest.approx(g, abs=2e-6)


@pytest.mark.parametrize("m", [1.55 + 0.0j, 1.55 + 0.1j, 1.75 + 0.44j, 2.2 + 0.7j])
def test_rayleigh_limit(m: complex) -> None:
    x = np.array([1e-3, 2e-3])
    qext, qsca, g = efficiencies(m, x)
    pol = (m * m - 1) / (m * m + 2)
    sca_ref = 8.0 / 3.0 * x**4 * abs(pol) ** 2
    np.testing.assert_allclose(qsca, sca_ref, rtol=1e-4)
    assert qsca[1] / qsca[0] == pytest.approx(16.0, rel=1e-4)
    if m.imag > 0:
        np.testing.assert_allclose(qext - qsca, 4 * x * pol.imag, rtol=1e-4)
    assert np.all(np.abs(g) < 1e-3)


@pytest.mark.parametrize("m", [1.33 + 0.0j, 1.5 + 0.01j, 1.75 + 0.44j, 10.0 + 10.0j])
def test_stable_from_1e_minus_3_to_1e4_and_extinction_paradox(m: complex) -> None:
    x = np.geomspace(1e-3, 1e4, 15)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        qext, qsca, g = efficiencies(m, x)
    for arr in (qext, qsca, g):
        assert np.all(np.isfinite(arr))
    assert np.all(qsca >= 0) and np.all(qext >= qsca * (1 - 1e-12))
    assert np.all(np.abs(g) <= 1)
    assert abs(qext[-1] - 2.0) < 0.01


def test_refractive_index_convention_and_validation() -> None:
    with pytest.raises(ValueError, match="n \\+ ik"):
        efficiencies(1.5 - 0.1j, 1.0)
    with pytest.raises(ValueError, match="size parameter"):
        efficiencies(1.5, np.array([1.0, 0.0]))
    qext, qsca, _ = efficiencies(1.5 + 0.1j, 2.0)
    assert qext > qsca  # absorbing


def test_refractive_index_tables() -> None:
    assert SOOT_INDEX(0.55) == pytest.approx(1.75 + 0.44j)
    assert WATER_SOLUBLE(10.0) == pytest.approx(1.82 + 0.09j)
    assert WATER_SOLUBLE(0.575) == pytest.approx(1.53 + 0.006j)
    with pytest.raises(ValueError, match="wavelength_um"):
        SOOT_INDEX(0.2)


def test_monodisperse_limit_is_a_single_sphere() -> None:
    pop = ParticlePopulation("mono", 0.3, 1.0, lambda lam: np.full(np.shape(lam), 1.5 + 0.01j))
    coeffs = spectral_coefficients(pop, np.array([0.5, 10.0]), n_radii=8)
    qext, qsca, g = efficiencies(1.5 + 0.01j, 2 * np.pi * 0.3 / np.array([0.5, 10.0]))
    np.testing.assert_allclose(coeffs.extinction, 3 * qext / (4 * 0.3e-6), rtol=1e-12)
    np.testing.assert_allclose(coeffs.scattering, 3 * qsca / (4 * 0.3e-6), rtol=1e-12)
    np.testing.assert_allclose(coeffs.asymmetry, g, rtol=1e-12)


def _trapezoid_reference(pop: ParticlePopulation, lam_um: float) -> tuple[float, float]:
    """Number-weighted integral done the long way: dense trapezoid in ln r over ±8σ."""
    s = np.log(pop.geometric_sigma)
    ln_r = np.log(pop.median_radius_um) + np.linspace(-8 * s, 8 * s, 1601)
    r = np.exp(ln_r)
    pdf = np.exp(-0.5 * ((ln_r - ln_r[800]) / s) ** 2)
    qext, qsca, _ = efficiencies(complex(pop.refractive_index(lam_um)), 2 * np.pi * r / lam_um)
    volume = np.trapz(pdf * 4 / 3 * np.pi * r**3, ln_r)
    ext = np.trapz(pdf * np.pi * r**2 * qext, ln_r) / volume
    sca = np.trapz(pdf * np.pi * r**2 * qsca, ln_r) / volume
    return ext * 1e6, sca * 1e6


@pytest.mark.parametrize("pop", [ORGANIC_SMOKE, SOOT], ids=lambda p: p.name)
def test_size_average_matches_independent_quadrature(pop: ParticlePopulation) -> None:
    lam = np.array([0.45, 0.55, 10.0])
    coeffs = spectral_coefficients(pop, lam, n_radii=96)
    for i, wl in enumerate(lam):
        ext, sca = _trapezoid_reference(pop, float(wl))
        assert coeffs.extinction[i] == pytest.approx(ext, rel=3e-4)
        assert coeffs.scattering[i] == pytest.approx(sca, rel=3e-4)


@pytest.fixture(scope="module")
def organic() -> SmokeOptics:
    return smoke_optics(ORGANIC_SMOKE)


@pytest.fixture(scope="module")
def soot() -> SmokeOptics:
    return smoke_optics(SOOT)


def test_smoke_optics_physics(organic: SmokeOptics, soot: SmokeOptics) -> None:
    for optics in (organic, soot):
        assert np.all(optics.albedo_rgb > 0) and np.all(optics.albedo_rgb <= 1)
        # Sub-micron smoke extinguishes blue more than red and is nearly transparent in LWIR.
        assert optics.extinction_rgb[2] > optics.extinction_rgb[1] > optics.extinction_rgb[0]
        assert 0 < optics.ratio_lwir_over_visible < 0.1
        assert optics.albedo_lwir < 0.05  # LWIR: absorption, not scattering
        assert optics.ratio_lwir_over_visible == pytest.approx(
            optics.extinction_lwir / optics.extinction_visible, rel=1e-12
        )
        # Luminance-weighted visible extinction ≈ Rec.709 luminance mix of the channels.
        y = np.array([0.2126, 0.7152, 0.0722])
        assert optics.extinction_visible == pytest.approx(float(y @ optics.extinction_rgb), rel=1e-2)
        np.testing.assert_array_equal(optics.smoke_color, optics.albedo_rgb)
        json.dumps(optics.describe())
    assert np.all(organic.albedo_rgb > 0.9)  # organic smoke: white-grey
    assert np.all(soot.albedo_rgb < 0.4)  # soot: black


def test_rgb_extinction_is_the_thin_slab_limit_of_a_spectral_render(organic: SmokeOptics) -> None:
    """colour-science integrates a thinly smoked white (D65) spectrum to linear sRGB; the
    per-channel −ln(transmittance)/d must equal extinction_rgb (the definition)."""
    lam_nm = np.arange(380.0, 781.0, 10.0)
    spectral = spectral_coefficients(ORGANIC_SMOKE, lam_nm * 1e-3)
    shape = colour.SpectralShape(380, 780, 10)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().trim(shape).interpolate(shape)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().trim(shape).interpolate(shape)
    to_rgb = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB)

    def linear_srgb(transmittance: np.ndarray) -> np.ndarray:
        sd = colour.SpectralDistribution(dict(zip(lam_nm, transmittance)))
        with warnings.catch_warnings():
            # colour notes that it integrates at 10 nm (ASTM E308) rather than 1 nm: intended.
            warnings.simplefilter("ignore", ColourRuntimeWarning)
            return to_rgb @ colour.sd_to_XYZ(sd, cmfs, d65, shape=shape)

    depth = 1e-4 / organic.extinction_visible
    white = linear_srgb(np.ones_like(lam_nm))
    smoked = linear_srgb(np.exp(-spectral.extinction * depth))
    np.testing.assert_allclose(-np.log(smoked / white) / depth, organic.extinction_rgb, rtol=1e-3)


def test_smoke_optics_converged_at_defaults(organic: SmokeOptics) -> None:
    fine = smoke_optics(ORGANIC_SMOKE, n_radii=96, n_wavelengths=61)
    np.testing.assert_allclose(organic.extinction_rgb, fine.extinction_rgb, rtol=1e-3)
    np.testing.assert_allclose(organic.albedo_rgb, fine.albedo_rgb, rtol=1e-3)
    assert organic.ratio_lwir_over_visible == pytest.approx(fine.ratio_lwir_over_visible, rel=2e-3)


def test_principled_volume_reproduces_cycles_coefficients(organic: SmokeOptics, soot: SmokeOptics) -> None:
    for optics in (organic, soot):
        pv = optics.principled_volume()
        # Cycles' svm_node_principled_volume: σ_s = D·c, σ_a = D·max(1−c,0)·max(1−√a,0).
        sigma_s = pv.extinction_scale * pv.color
        sigma_a = pv.extinction_scale * np.maximum(1 - pv.color, 0) * np.maximum(
            1 - np.sqrt(pv.absorption_color), 0
        )
        np.testing.assert_allclose(sigma_s + sigma_a, optics.extinction_rgb, rtol=1e-9)
        np.testing.assert_allclose(sigma_s / (sigma_s + sigma_a), optics.albedo_rgb, rtol=1e-9)
        assert np.all((pv.color >= 0) & (pv.color <= 1))
        assert np.all((pv.absorption_color >= 0) & (pv.absorption_color <= 1))


def test_smoke_optics_validation() -> None:
    with pytest.raises(ValueError, match="band_m"):
        smoke_optics(SOOT, band_m=(0.0, np.inf))
    with pytest.raises(ValueError, match="wavelength_um"):
        smoke_optics(SOOT, band_m=(40e-6, 50e-6))
    with pytest.raises(ValueError, match="geometric_sigma"):
        ParticlePopulation("bad", 0.1, 0.9, SOOT_INDEX)
    with pytest.raises(ValueError, match="median_radius_um"):
        ParticlePopulation("bad", -0.1, 1.5, SOOT_INDEX)
