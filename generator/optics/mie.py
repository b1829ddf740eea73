"""Smoke optics from Mie theory: why smoke hides the scene in RGB but not in LWIR.

Smoke particles are a few tens to hundreds of nanometres across: comparable to visible
wavelengths (size parameter x = 2πr/λ ~ 1, strong scattering) but far smaller than 8-14 µm
(x ~ 0.03, Rayleigh regime, where scattering falls as x⁴ and only weak absorption is left).
This module turns a particle population (lognormal sizes + complex refractive index) into the
numbers the generator needs: per-channel visible extinction and albedo (the smoke's colour),
LWIR band extinction and their ratio.

Conventions (documented in docs/optics.md):

- Refractive index m = n + ik with k >= 0 (Bohren & Huffman). miepython uses n - ik; the
  wrapper conjugates explicitly.
- Coefficients are per unit particle *volume fraction* f_v: σ [m⁻¹] for f_v = 1. Multiply by the
  actual volume fraction (e.g. 1e-7) for a physical coefficient. Ratios and albedos do not
  depend on this choice.
- Size distribution: lognormal in number with median radius r_g and geometric std σ_g.
  Cross-sections weight by r², so the average is taken over the area-weighted lognormal
  (median r_g·exp(2 ln²σ_g), same σ_g; Hatch-Choate), by the trapezoid rule in ln r over ±6
  standard deviations. Gauss-Hermite was tried and rejected: for weakly absorbing particles
  Q(x) carries interference oscillations and narrow resonances that its few central nodes
  alias (0.1-1.7% errors at 32-64 nodes), whereas uniform nodes reach 4e-5 at 64 (see
  benchmarks/optics_mie_convergence.py and docs/optics.md).
  Per unit volume fraction, σ = 3⟨Q⟩_area / (4 r_eff), r_eff = r_g·exp(2.5 ln²σ_g).
- RGB channels: the thin-smoke limit of rendering a D65-lit scene in linear sRGB. For channel c
  with sRGB colour-matching function r̄_c(λ) (CIE 1931 2° CMFs through the sRGB matrix, from
  colour-science), σ_c = ∫σ(λ)·D65(λ)·r̄_c(λ)dλ / ∫D65(λ)·r̄_c(λ)dλ: then exp(-σ_c·d) matches the
  spectral transmittance of every channel to first order in optical depth.
- Visible reference extinction (for the LWIR/visible ratio): the photopic (CIE ȳ) weighted
  extinction under D65, i.e. what a luminance meter would see.
- LWIR band extinction: Planck-weighted mean over the band at `lwir_reference_temperature_k`
  (300 K by default), i.e. the extinction a thin slab applies to a 300 K scene's in-band radiance.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import colour
import miepython
import numpy as np
from colour.colorimetry import planck_law

from generator.optics.planck import LWIR_BAND_M, validate_band
from generator.optics.refractive_index import SOOT as SOOT_INDEX
from generator.optics.refractive_index import WATER_SOLUBLE as WATER_SOLUBLE_INDEX

VISIBLE_RANGE_NM: tuple[float, float] = (380.0, 780.0)
#: Half-width of the size quadrature in standard deviations of ln r: cutting the area-weighted
#: lognormal at ±6 costs < 1e-7 relative (measured; largest in the LWIR, where Q grows with r).
_XI_MAX = 6.0


@dataclass(frozen=True, eq=False)
class ParticlePopulation:
    """Lognormal (in number) population of homogeneous spheres."""

    name: str
    median_radius_um: float
    geometric_sigma: float
    refractive_index: Callable[[np.ndarray], np.ndarray]
    source: str = ""

    def __post_init__(self) -> None:
        if not np.isfinite(self.median_radius_um) or self.median_radius_um <= 0:
            raise ValueError(f"median_radius_um must be > 0, got {self.median_radius_um!r}")
        if not np.isfinite(self.geometric_sigma) or self.geometric_sigma < 1:
            raise ValueError(f"geometric_sigma must be >= 1, got {self.geometric_sigma!r}")

    @property
    def effective_radius_um(self) -> float:
        """Area-weighted mean radius ⟨r³⟩/⟨r²⟩ = r_g·exp(2.5 ln²σ_g)."""
        s = np.log(self.geometric_sigma)
        return float(self.median_radius_um * np.exp(2.5 * s * s))


ORGANIC_SMOKE = ParticlePopulation(
    name="organic_smoke",
    median_radius_um=0.065,
    geometric_sigma=1.6,
    refractive_index=WATER_SOLUBLE_INDEX,
    source=(
        "Sizes: fresh biomass-burning smoke, count median diameter 0.13 µm, sigma_g 1.6, within "
        "the ranges reviewed by Reid, Koppmann, Eck & Eleuterio (2005), Atmos. Chem. Phys. 5, "
        "799-825. Refractive index: OPAC water-soluble component (Hess et al. 1998)."
    ),
)

SOOT = ParticlePopulation(
    name="soot",
    median_radius_um=0.0118,
    geometric_sigma=2.0,
    refractive_index=SOOT_INDEX,
    source="OPAC soot component: r_mod 0.0118 µm, sigma 2.00, refractive index (Hess et al. 1998).",
)


def efficiencies(m: complex, x: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mie extinction and scattering efficiencies and asymmetry g for spheres of index m.

    m = n + ik with k >= 0 (absorbing); x = 2πr/λ > 0. Tested stable for x in [1e-3, 1e4].
    """
    m = complex(m)
    if not (np.isfinite(m.real) and np.isfinite(m.imag)) or m.real <= 0:
        raise ValueError(f"m must be finite with a positive real part, got {m!r}")
    if m.imag < 0:
        raise ValueError(f"m must use the n + ik convention with k >= 0, got {m!r}")
    xs = np.asarray(x, dtype=np.float64)
    if not np.all(np.isfinite(xs)) or np.any(xs <= 0):
        raise ValueError("x (size parameter) must be finite and > 0")
    flat = np.atleast_1d(xs).ravel()
    qext, qsca, _qback, g = miepython.efficiencies_mx(m.conjugate(), flat)
    shape = xs.shape
    return (
        np.asarray(qext, dtype=np.float64).reshape(shape),
        np.asarray(qsca, dtype=np.float64).reshape(shape),
        np.asarray(g, dtype=np.float64).reshape(shape),
    )


@dataclass(frozen=True, eq=False)
class SpectralCoefficients:
    """Size-averaged optical coefficients per unit volume fraction (m⁻¹) against wavelength."""

    wavelength_um: np.ndarray
    extinction: np.ndarray
    scattering: np.ndarray
    asymmetry: np.ndarray

    @property
    def absorption(self) -> np.ndarray:
        return self.extinction - self.scattering

    @property
    def albedo(self) -> np.ndarray:
        return self.scattering / self.extinction


def spectral_coefficients(
    population: ParticlePopulation, wavelength_um: np.ndarray, n_radii: int = 64
) -> SpectralCoefficients:
    """Extinction, scattering and asymmetry of the population at each wavelength (µm)."""
    if not isinstance(n_radii, int) or n_radii < 3:
        raise ValueError(f"n_radii must be an int >= 3, got {n_radii!r}")
    lam = np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64))
    if lam.ndim != 1 or not np.all(np.isfinite(lam)) or np.any(lam <= 0):
        raise ValueError("wavelength_um must be a 1-D array of positive finite values")
    s = np.log(population.geometric_sigma)
    xi = np.zeros(1) if s == 0 else np.linspace(-_XI_MAX, _XI_MAX, n_radii)
    w = np.exp(-0.5 * xi * xi)
    w /= w.sum()
    radii = population.median_radius_um * np.exp(2.0 * s * s + s * xi)
    m = np.asarray(population.refractive_index(lam), dtype=np.complex128)
    ext = np.empty_like(lam)
    sca = np.empty_like(lam)
    asym = np.empty_like(lam)
    for i, (wl, mi) in enumerate(zip(lam, m)):
        qext, qsca, g = efficiencies(complex(mi), 2.0 * np.pi * radii / wl)
        ext[i] = np.dot(w, qext)
        sca[i] = np.dot(w, qsca)
        asym[i] = np.dot(w, qsca * g) / sca[i]
    per_volume = 3.0 / (4.0 * population.effective_radius_um * 1e-6)
    return SpectralCoefficients(lam, ext * per_volume, sca * per_volume, asym)


@lru_cache(maxsize=1)
def _visible_weights() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """1-nm grid (nm), D65·sRGB-CMF weights (3, N) and D65·ȳ weights (N,), unnormalised."""
    lo, hi = VISIBLE_RANGE_NM
    grid = np.arange(lo, hi + 0.5, 1.0)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    xyz = np.stack([np.interp(grid, cmfs.wavelengths, cmfs.values[:, i]) for i in range(3)])
    d65 = colour.SDS_ILLUMINANTS["D65"]
    illuminant = np.interp(grid, d65.wavelengths, d65.values)
    rgb = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB) @ xyz
    return grid, rgb * illuminant, xyz[1] * illuminant


def _trapezoid(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    dx = np.diff(x)
    return 0.5 * np.sum(dx * (y[..., 1:] + y[..., :-1]), axis=-1)


def _weighted_means(values: np.ndarray, grid: np.ndarray, weights: np.ndarray) -> np.ndarray:
    return _trapezoid(values * weights, grid) / _trapezoid(weights, grid)


@dataclass(frozen=True, eq=False)
class PrincipledVolumeParameters:
    """Cycles Principled Volume inputs that reproduce σ_ext and albedo per RGB channel.

    Cycles sets σ_s = D·color and σ_a = D·max(1−color, 0)·max(1−sqrt(absorption_color), 0);
    with D = extinction_scale·(volume fraction) the three channels' extinction and albedo match
    the Mie values. `anisotropy` is the luminance-weighted asymmetry parameter g.
    """

    extinction_scale: float
    color: np.ndarray
    absorption_color: np.ndarray
    anisotropy: float


@dataclass(frozen=True, eq=False)
class SmokeOptics:
    """Band-averaged smoke optics; coefficients in m⁻¹ per unit particle volume fraction."""

    population: str
    extinction_rgb: np.ndarray
    scattering_rgb: np.ndarray
    albedo_rgb: np.ndarray
    asymmetry_rgb: np.ndarray
    extinction_visible: float
    asymmetry_visible: float
    extinction_lwir: float
    scattering_lwir: float
    ratio_lwir_over_visible: float
    smoke_color: np.ndarray
    band_m: tuple[float, float]
    lwir_reference_temperature_k: float

    @property
    def albedo_lwir(self) -> float:
        return self.scattering_lwir / self.extinction_lwir

    @property
    def extinction_rgb_relative(self) -> np.ndarray:
        """Per-channel extinction over the luminance-weighted one (1 for grey smoke)."""
        return self.extinction_rgb / self.extinction_visible

    def principled_volume(self) -> PrincipledVolumeParameters:
        """Principled Volume colour/absorption colour reproducing these coefficients."""
        scale = float(np.max(self.extinction_rgb))
        color = self.scattering_rgb / scale
        absorption = self.extinction_rgb - self.scattering_rgb
        root = 1.0 - absorption / (scale * (1.0 - color))
        return PrincipledVolumeParameters(
            extinction_scale=scale,
            color=color,
            absorption_color=np.clip(root, 0.0, 1.0) ** 2,
            anisotropy=self.asymmetry_visible,
        )

    def describe(self) -> dict[str, object]:
        """JSON-able summary for dataset.json["optics"] (the lead adds the ambient temperature)."""
        return {
            "population": self.population,
            "band_um": [self.band_m[0] * 1e6, self.band_m[1] * 1e6],
            "coefficient_units": "1/m per unit particle volume fraction",
            "sigma_ratio_lwir_over_visible": self.ratio_lwir_over_visible,
            "visible_extinction_rgb": self.extinction_rgb.tolist(),
            "visible_extinction_rgb_relative": self.extinction_rgb_relative.tolist(),
            "visible_extinction_luminance": self.extinction_visible,
            "albedo_rgb": self.albedo_rgb.tolist(),
            "smoke_color": self.smoke_color.tolist(),
            "asymmetry_visible": self.asymmetry_visible,
            "lwir_extinction": self.extinction_lwir,
            "lwir_albedo": self.albedo_lwir,
            "lwir_reference_temperature_k": self.lwir_reference_temperature_k,
        }


def smoke_optics(
    population: ParticlePopulation = ORGANIC_SMOKE,
    band_m: tuple[float, float] = LWIR_BAND_M,
    n_radii: int = 64,
    n_wavelengths: int = 41,
    lwir_reference_temperature_k: float = 300.0,
) -> SmokeOptics:
    """Visible RGB and LWIR optics of a particle population (see the module docstring).

    n_wavelengths Mie wavelengths span 380-780 nm (σ is interpolated log-log onto the 1-nm
    colour-matching grid) and, separately, the LWIR band (trapezoid with Planck weights).
    """
    lo, hi = validate_band(band_m)
    if not np.isfinite(hi) or lo <= 0:
        raise ValueError(f"band_m must be a finite band for smoke optics, got {band_m!r}")
    if not isinstance(n_wavelengths, int) or n_wavelengths < 2:
        raise ValueError(f"n_wavelengths must be an int >= 2, got {n_wavelengths!r}")
    if not np.isfinite(lwir_reference_temperature_k) or lwir_reference_temperature_k <= 0:
        raise ValueError("lwir_reference_temperature_k must be > 0")

    lwir_um = np.linspace(lo, hi, n_wavelengths) * 1e6
    lwir = spectral_coefficients(population, lwir_um, n_radii)
    planck = np.asarray(planck_law(lwir_um * 1e-6, lwir_reference_temperature_k), dtype=np.float64)
    extinction_lwir = float(_weighted_means(lwir.extinction, lwir_um, planck))
    scattering_lwir = float(_weighted_means(lwir.scattering, lwir_um, planck))

    grid_nm, rgb_w, y_w = _visible_weights()
    vis_um = np.linspace(VISIBLE_RANGE_NM[0], VISIBLE_RANGE_NM[1], n_wavelengths) * 1e-3
    vis = spectral_coefficients(population, vis_um, n_radii)
    log_grid = np.log(grid_nm * 1e-3)

    def on_grid(values: np.ndarray) -> np.ndarray:
        return np.exp(np.interp(log_grid, np.log(vis_um), np.log(values)))

    ext = on_grid(vis.extinction)
    sca = on_grid(vis.scattering)
    sca_g = sca * np.interp(log_grid, np.log(vis_um), vis.asymmetry)
    extinction_rgb = _weighted_means(ext, grid_nm, rgb_w)
    scattering_rgb = _weighted_means(sca, grid_nm, rgb_w)
    asymmetry_rgb = _weighted_means(sca_g, grid_nm, rgb_w) / scattering_rgb
    extinction_visible = float(_weighted_means(ext, grid_nm, y_w))
    asymmetry_visible = float(
        _weighted_means(sca_g, grid_nm, y_w) / _weighted_means(sca, grid_nm, y_w)
    )

    albedo_rgb = scattering_rgb / extinction_rgb
    return SmokeOptics(
        population=population.name,
        extinction_rgb=extinction_rgb,
        scattering_rgb=scattering_rgb,
        albedo_rgb=albedo_rgb,
        asymmetry_rgb=asymmetry_rgb,
        extinction_visible=extinction_visible,
        asymmetry_visible=asymmetry_visible,
        extinction_lwir=extinction_lwir,
        scattering_lwir=scattering_lwir,
        ratio_lwir_over_visible=extinction_lwir / extinction_visible,
        smoke_color=np.clip(albedo_rgb, 0.0, 1.0),
        band_m=(lo, hi),
        lwir_reference_temperature_k=float(lwir_reference_temperature_k),
    )
