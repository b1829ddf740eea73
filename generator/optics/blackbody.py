"""Visible colour and brightness of a blackbody, for fire glow in the RGB render.

A flame glows as a blackbody at its temperature (soot emission is close to grey): its
colour is the chromaticity of Planck's spectrum under the CIE 1931 2° observer, and its
brightness scales with the photopic luminance `Y(T) = ∫ B(λ, T) ȳ(λ) dλ`, which falls by
orders of magnitude below ~800 K, so warm gas does not glow visibly. The spectrum is
integrated here at 1 nm over 360–830 nm with the CIE table (taken from colour-science's
data) and converted to linear Rec.709/sRGB primaries, D65 white (IEC 61966-2-1), the
scene-linear space Blender renders in.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

#: Planck's constants as in CIE 15:2004 (c1L = 2hc², c2 = hc/k), SI units.
C1L = 1.191042972e-16  # W·m²·sr⁻¹
C2 = 1.4388e-2  # m·K

#: CIE XYZ -> linear sRGB (D65), IEC 61966-2-1:1999.
XYZ_TO_LINEAR_SRGB = np.array([
    [3.2406, -1.5372, -0.4986],
    [-0.9689, 1.8758, 0.0415],
    [0.0557, -0.2040, 1.0570],
])

#: Below this, the luminance is under 1e-30 of a 1300 K flame's: treated as exactly dark.
MIN_GLOW_TEMPERATURE_K = 150.0
#: Colder gas takes this temperature's colour; its luminance is ~1e-9 of 1300 K's, so it never shows.
MIN_CHROMATICITY_K = 500.0


@lru_cache(maxsize=1)
def _cmfs() -> tuple[np.ndarray, np.ndarray]:
    """Wavelengths (m) and the CIE 1931 2° colour-matching functions at 1 nm."""
    from colour import MSDS_CMFS

    cmfs = MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    nm = np.arange(360, 831, dtype=float)
    return nm * 1e-9, np.asarray(cmfs[nm], dtype=float)


def _spectral_radiance(wavelength_m: np.ndarray, temperature_k: float) -> np.ndarray:
    """Planck's law, written with exp(-x) so that low temperatures underflow to 0 quietly."""
    x = C2 / (wavelength_m * temperature_k)
    decay = np.exp(-x)
    return C1L / wavelength_m**5 * decay / (1.0 - decay)


def _validate(temperature_k: float) -> float:
    t = float(temperature_k)
    if not np.isfinite(t) or t <= 0:
        raise ValueError(f"blackbody temperature must be a positive finite number of kelvin, got {temperature_k}")
    return t


def blackbody_xyz(temperature_k: float) -> np.ndarray:
    """CIE XYZ of a blackbody (relative units: W·m⁻²·sr⁻¹ weighted by the CMFs, no 683 lm/W)."""
    t = _validate(temperature_k)
    if t < MIN_GLOW_TEMPERATURE_K:
        return np.zeros(3)
    wavelengths, cmfs = _cmfs()
    spectrum = _spectral_radiance(wavelengths, t)
    return np.trapz(spectrum[:, None] * cmfs, wavelengths, axis=0)


def relative_luminance(temperature_k: float, reference_k: float) -> float:
    """Y(T) / Y(reference): how bright gas at T glows next to gas at the reference temperature."""
    reference = blackbody_xyz(reference_k)[1]
    if reference <= 0:
        raise ValueError(f"reference temperature {reference_k} K has no visible luminance")
    return float(blackbody_xyz(temperature_k)[1] / reference)


def chromaticity_rgb(temperature_k: float) -> np.ndarray:
    """Linear sRGB colour of the blackbody with luminance 1. Channels outside the sRGB gamut
    (blue below ~1900 K) are clipped to 0 and the colour rescaled back to luminance 1."""
    xyz = blackbody_xyz(max(_validate(temperature_k), MIN_CHROMATICITY_K))
    rgb = np.clip(XYZ_TO_LINEAR_SRGB @ (xyz / xyz[1]), 0.0, None)
    return rgb / float(np.linalg.solve(XYZ_TO_LINEAR_SRGB, rgb)[1])


def glow_table(ambient_k: float, flame_k: float, strength: float, points: int) -> list[list[float]]:
    """Rows (f, r, g, b): emission of gas at T = ambient + f·(flame − ambient), f in [0, 1]:
    the blackbody colour times `strength · Y(T)/Y(flame)`, in scene-linear RGB per metre."""
    rows = []
    for f in np.linspace(0.0, 1.0, points):
        t = ambient_k + f * (flame_k - ambient_k)
        rgb = strength * relative_luminance(t, flame_k) * chromaticity_rgb(t)
        rows.append([float(f), *(float(c) for c in rgb)])
    return rows
