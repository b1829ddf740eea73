"""In-band blackbody radiance for thermal (LWIR) cameras, its derivative and its inverse.

A thermal camera integrates Planck's spectral radiance over its pass band, so the signal is
`L_band(T) = ∫ B(λ, T) dλ` over the band, not σT⁴/π (the 8–14 µm band holds 38% of σT⁴/π at
300 K but 11% at 1000 K). The spectral radiance comes from colour-science's `planck_law`
(CIE 15:2004 form, c1 = 3.741771e-16 W·m², c2 = 1.4388e-2 m·K, the ITS-90 value).

Quadrature: the integral is done in the dimensionless frequency u = c2 / (λT), where
`L = T⁴ ∫ φ(u) du` with `φ(u) = B(c2/u, 1 K) · c2/u²` a universal function (B(λ, T) = T⁵ B(λT, 1 K)
holds exactly). In u the integrand is u³/(eᵘ − 1) up to a constant: smooth, with its nearest
singularities at u = ±2πi. Composite Gauss–Legendre with panels at most `panel_width` wide
therefore converges geometrically for every temperature, whereas a fixed rule in λ would need
ever more nodes as the integrand piles up at the short-wavelength edge at low T. The range is cut
`span` above its lower end; beyond that the integrand has fallen by e^-span and is below
double precision. See docs/optics.md for the measured error against node count and time.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from colour.colorimetry import planck_law
from colour.colorimetry.blackbody import CONSTANT_C2

LWIR_BAND_M: tuple[float, float] = (8e-6, 14e-6)

#: Highest temperature the inverse (brightness temperature) searches up to.
MAX_BRIGHTNESS_TEMPERATURE_K = 1e7


@dataclass(frozen=True)
class PlanckQuadrature:
    """Composite Gauss–Legendre rule in u = c2/(λT); the defaults reach ~1e-13 relative error."""

    nodes_per_panel: int = 8
    panel_width: float = 4.0
    span: float = 64.0

    def __post_init__(self) -> None:
        if not isinstance(self.nodes_per_panel, int) or self.nodes_per_panel < 1:
            raise ValueError(f"nodes_per_panel must be a positive int, got {self.nodes_per_panel!r}")
        if not np.isfinite(self.panel_width) or self.panel_width <= 0:
            raise ValueError(f"panel_width must be positive and finite, got {self.panel_width!r}")
        if not np.isfinite(self.span) or self.span <= 0:
            raise ValueError(f"span must be positive and finite, got {self.span!r}")


DEFAULT_QUADRATURE = PlanckQuadrature()


def validate_band(band_m: tuple[float, float]) -> tuple[float, float]:
    """Return the band as floats, or raise ValueError: need 0 <= λ_lo < λ_hi <= inf (metres)."""
    try:
        lo, hi = (float(v) for v in band_m)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"band_m must be a pair of wavelengths in metres, got {band_m!r}") from exc
    if np.isnan(lo) or np.isnan(hi) or lo < 0 or not np.isfinite(lo) or not hi > lo:
        raise ValueError(f"band_m must satisfy 0 <= lo < hi <= inf (metres), got {band_m!r}")
    return lo, hi


def _validate_temperature(temperature_k: float | np.ndarray) -> np.ndarray:
    t = np.asarray(temperature_k, dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise ValueError("temperature_k must be finite (got NaN or inf)")
    if np.any(t <= 0):
        raise ValueError(f"temperature_k must be > 0 K, got minimum {t.min()!r}")
    return t


def _phi(u: np.ndarray) -> np.ndarray:
    """Planck integrand in u per K⁴: B(c2/u, 1 K)·c2/u², zero at u = 0 and u = inf."""
    u = np.asarray(u, dtype=np.float64)
    ok = np.isfinite(u) & (u > 0)
    uu = u if ok.all() else u[ok]
    # expm1 overflows for u > ~709 (T of a few K in the LWIR): the radiance there is below
    # the smallest double, so the 0 that colour returns is the right answer.
    with np.errstate(over="ignore"):
        spectral = np.asarray(planck_law(CONSTANT_C2 / uu, 1.0), dtype=np.float64)
    values = spectral.reshape(uu.shape) * (CONSTANT_C2 / (uu * uu))
    if uu is u:
        return values
    out = np.zeros_like(u)
    out[ok] = values
    return out


@lru_cache(maxsize=32)
def _legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    nodes, weights = np.polynomial.legendre.leggauss(n)
    nodes.setflags(write=False)
    weights.setflags(write=False)
    return nodes, weights


def _u_limits(t: np.ndarray, band: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = band
    u_lo = np.zeros_like(t) if np.isinf(hi) else CONSTANT_C2 / (hi * t)
    u_hi = np.full_like(t, np.inf) if lo == 0 else CONSTANT_C2 / (lo * t)
    return u_lo, u_hi


def _integral_u(u_lo: np.ndarray, u_hi: np.ndarray, quad: PlanckQuadrature) -> np.ndarray:
    """∫ φ(u) du over [u_lo, u_hi] (1-D arrays), panels grouped by count to bound memory."""
    top = np.minimum(u_hi, u_lo + quad.span)
    width = top - u_lo
    panels = np.maximum(1, np.ceil(width / quad.panel_width)).astype(np.int64)
    x, w = _legendre(quad.nodes_per_panel)
    result = np.empty_like(u_lo)
    for p in np.unique(panels):
        sel = panels == p
        h = width[sel] / p
        starts = u_lo[sel, None] + h[:, None] * np.arange(p)[None, :]
        nodes = starts[:, :, None] + 0.5 * h[:, None, None] * (x + 1.0)
        values = _phi(nodes) * w
        result[sel] = 0.5 * h * values.sum(axis=(1, 2))
    return result


def band_radiance(
    temperature_k: float | np.ndarray,
    band_m: tuple[float, float] = LWIR_BAND_M,
    quadrature: PlanckQuadrature = DEFAULT_QUADRATURE,
) -> np.ndarray:
    """Blackbody radiance integrated over `band_m`, W·m⁻²·sr⁻¹ (same shape as the input)."""
    band = validate_band(band_m)
    t = _validate_temperature(temperature_k)
    flat = t.ravel()
    u_lo, u_hi = _u_limits(flat, band)
    return (flat**4 * _integral_u(u_lo, u_hi, quadrature)).reshape(t.shape)


def _radiance_and_slope(
    t: np.ndarray, band: tuple[float, float], quad: PlanckQuadrature
) -> tuple[np.ndarray, np.ndarray]:
    """L_band and dL_band/dT for validated 1-D temperatures, sharing one quadrature.

    dL/dT follows from Leibniz's rule on L = T⁴ ∫ φ(u) du with u-limits c2/(λT):
    dL/dT = T³ (4 ∫φ − u_hi φ(u_hi) + u_lo φ(u_lo)); no finite differences.
    """
    u_lo, u_hi = _u_limits(t, band)
    integral = _integral_u(u_lo, u_hi, quad)
    finite_hi = np.where(np.isfinite(u_hi), u_hi, 0.0)
    edges = u_lo * _phi(u_lo) - finite_hi * _phi(finite_hi)
    return t**4 * integral, t**3 * (4.0 * integral + edges)


def band_radiance_derivative(
    temperature_k: float | np.ndarray,
    band_m: tuple[float, float] = LWIR_BAND_M,
    quadrature: PlanckQuadrature = DEFAULT_QUADRATURE,
) -> np.ndarray:
    """dL_band/dT in W·m⁻²·sr⁻¹·K⁻¹ (exact differentiation of the quadrature's integrand)."""
    band = validate_band(band_m)
    t = _validate_temperature(temperature_k)
    return _radiance_and_slope(t.ravel(), band, quadrature)[1].reshape(t.shape)


@dataclass(frozen=True, eq=False)
class _InverseGrid:
    log_t: np.ndarray
    log_l: np.ndarray


@lru_cache(maxsize=16)
def _inverse_grid(band: tuple[float, float], quad: PlanckQuadrature) -> _InverseGrid:
    """log L against log T on a grid whose radiance is representable: brackets for Newton."""
    t = np.geomspace(0.5, MAX_BRIGHTNESS_TEMPERATURE_K, 400)
    radiance = band_radiance(t, band, quad)
    keep = radiance > 1e-290
    return _InverseGrid(np.log(t[keep]), np.log(radiance[keep]))


def brightness_temperature(
    radiance: float | np.ndarray,
    band_m: tuple[float, float] = LWIR_BAND_M,
    quadrature: PlanckQuadrature = DEFAULT_QUADRATURE,
) -> np.ndarray:
    """Temperature of the blackbody with this in-band radiance (K); 0 radiance maps to 0 K.

    Monotone solve: a tabulated log L(log T) gives a bracket, then Newton on log L with
    bisection whenever a step leaves the bracket; stops at a 1e-13 relative step.
    """
    band = validate_band(band_m)
    lum = np.asarray(radiance, dtype=np.float64)
    if not np.all(np.isfinite(lum)):
        raise ValueError("radiance must be finite (got NaN or inf)")
    if np.any(lum < 0):
        raise ValueError(f"radiance must be >= 0, got minimum {lum.min()!r}")
    grid = _inverse_grid(band, quadrature)
    flat = lum.ravel()
    out = np.zeros_like(flat)
    positive = flat > 0
    if not np.any(positive):
        return out.reshape(lum.shape)
    target = np.log(flat[positive])
    if np.any(target > grid.log_l[-1]):
        raise ValueError(
            f"radiance {flat.max()!r} exceeds that of a {MAX_BRIGHTNESS_TEMPERATURE_K:g} K blackbody"
        )
    idx = np.clip(np.searchsorted(grid.log_l, target), 1, grid.log_l.size - 1)
    lo = np.where(target < grid.log_l[0], np.log(1e-3), grid.log_t[idx - 1])
    hi = np.where(target < grid.log_l[0], grid.log_t[0], grid.log_t[idx])
    frac = np.clip((target - grid.log_l[idx - 1]) / (grid.log_l[idx] - grid.log_l[idx - 1]), 0, 1)
    s = np.where(target < grid.log_l[0], 0.5 * (lo + hi), lo + frac * (hi - lo))
    active = np.ones(target.shape, dtype=bool)
    for _ in range(200):
        t = np.exp(s[active])
        rad, drad = _radiance_and_slope(t, band, quadrature)
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(rad > 0, np.log(rad) - target[active], -np.inf)
            slope = np.where(rad > 0, drad * t / rad, 0.0)  # d log L / d log T
            step = np.where(slope > 0, -g / slope, np.nan)
        lo_a, hi_a = lo[active], hi[active]
        lo_a = np.where(g < 0, s[active], lo_a)
        hi_a = np.where(g > 0, s[active], hi_a)
        proposal = s[active] + step
        converged = (np.abs(step) < 1e-13) | (hi_a - lo_a < 1e-13)
        bad = ~np.isfinite(proposal) | (proposal <= lo_a) | (proposal >= hi_a)
        newton_or_bisect = np.where(bad, 0.5 * (lo_a + hi_a), proposal)
        new_s = np.where(converged & np.isfinite(proposal), proposal, newton_or_bisect)
        lo[active], hi[active] = lo_a, hi_a
        s[active] = new_s
        idx_active = np.flatnonzero(active)
        active[idx_active[converged]] = False
        if not np.any(active):
            break
    out[positive] = np.exp(s)
    return out.reshape(lum.shape)


@dataclass(frozen=True, eq=False)
class RadianceTable:
    """Monotone (T, L_band) samples whose linear interpolant is within `rel_tol` of L_band.

    Meant for Blender shaders (a float curve or colour ramp driven by temperature). Note that a
    Blender ColorRamp holds at most 32 stops; use a float curve with vector handles otherwise.
    """

    temperatures_k: np.ndarray
    radiance: np.ndarray
    band_m: tuple[float, float] = LWIR_BAND_M
    rel_tol: float = 1e-3

    def __post_init__(self) -> None:
        t = np.asarray(self.temperatures_k, dtype=np.float64)
        lum = np.asarray(self.radiance, dtype=np.float64)
        if t.ndim != 1 or t.shape != lum.shape or t.size < 2:
            raise ValueError("temperatures_k and radiance must be 1-D arrays of equal length >= 2")
        if not np.all(np.diff(t) > 0) or not np.all(np.diff(lum) > 0):
            raise ValueError("temperatures_k and radiance must be strictly increasing")
        t.setflags(write=False)
        lum.setflags(write=False)
        object.__setattr__(self, "temperatures_k", t)
        object.__setattr__(self, "radiance", lum)

    def radiance_at(self, temperature_k: float | np.ndarray) -> np.ndarray:
        """Linear interpolation of L_band; clamps outside the table's range."""
        return np.interp(temperature_k, self.temperatures_k, self.radiance)

    def temperature_at(self, radiance: float | np.ndarray) -> np.ndarray:
        """Linear inverse interpolation (the table is monotone); clamps outside its range."""
        return np.interp(radiance, self.radiance, self.temperatures_k)


def radiance_table(
    t_min_k: float,
    t_max_k: float,
    band_m: tuple[float, float] = LWIR_BAND_M,
    rel_tol: float = 1e-3,
) -> RadianceTable:
    """Tabulate L_band on [t_min, t_max], bisecting intervals until linear interpolation is
    within rel_tol (checked at midpoints with a safety factor 2, since for a smooth convex
    function the chord error peaks near the middle)."""
    if not (np.isfinite(t_min_k) and np.isfinite(t_max_k)) or not 0 < t_min_k < t_max_k:
        raise ValueError(f"need 0 < t_min_k < t_max_k (finite), got {t_min_k!r}, {t_max_k!r}")
    if not 0 < rel_tol <= 0.1:
        raise ValueError(f"rel_tol must be in (0, 0.1], got {rel_tol!r}")
    band = validate_band(band_m)
    t = np.linspace(t_min_k, t_max_k, 9)
    lum = band_radiance(t, band)
    if lum[0] <= 0:
        raise ValueError(f"t_min_k={t_min_k!r} is too cold: its in-band radiance underflows to 0")
    for _ in range(60):
        mid = 0.5 * (t[:-1] + t[1:])
        exact = band_radiance(mid, band)
        chord = 0.5 * (lum[:-1] + lum[1:])
        split = np.abs(chord - exact) > 0.5 * rel_tol * exact
        if not np.any(split):
            break
        t = np.sort(np.concatenate([t, mid[split]]))
        lum = np.sort(np.concatenate([lum, exact[split]]))
    return RadianceTable(t, lum, band, rel_tol)
