"""Analytic LWIR radiative transfer through an absorbing-emitting smoke slab.

In the LWIR, smoke scattering is negligible (single-scattering albedo ~1e-3, see mie.py), so a
homogeneous isothermal slab is the closed-form reference for the generator's thermal render:
`L = τ·L_surface + (1 − τ)·L_band(T_smoke)` with τ = exp(−σ·d) (Beer-Lambert + Kirchhoff).
"""

from __future__ import annotations

import numpy as np

from generator.optics.planck import LWIR_BAND_M, band_radiance


def _validate_optical_depth(optical_depth: float | np.ndarray) -> np.ndarray:
    od = np.asarray(optical_depth, dtype=np.float64)
    if np.any(np.isnan(od)):
        raise ValueError("optical_depth must not be NaN")
    if np.any(od < 0):
        raise ValueError(f"optical_depth must be >= 0, got minimum {od.min()!r}")
    return od


def transmittance(optical_depth: float | np.ndarray) -> np.ndarray:
    """exp(−optical_depth); +inf and very deep slabs give exactly 0, never NaN or a warning."""
    od = _validate_optical_depth(optical_depth)
    with np.errstate(under="ignore"):
        return np.exp(-od)


def slab_radiance(
    surface_radiance: float | np.ndarray,
    optical_depth: float | np.ndarray,
    smoke_temperature_k: float | np.ndarray,
    band_m: tuple[float, float] = LWIR_BAND_M,
) -> np.ndarray:
    """In-band radiance leaving a slab in front of a surface (arrays broadcast together).

    Uses −expm1(−τ) for the emissivity so thin slabs keep full relative precision.
    """
    surface = np.asarray(surface_radiance, dtype=np.float64)
    if not np.all(np.isfinite(surface)) or np.any(surface < 0):
        raise ValueError("surface_radiance must be finite and >= 0")
    od = _validate_optical_depth(optical_depth)
    smoke = band_radiance(smoke_temperature_k, band_m)
    with np.errstate(under="ignore"):
        tau = np.exp(-od)
        emissivity = -np.expm1(-od)
    return tau * surface + emissivity * smoke
