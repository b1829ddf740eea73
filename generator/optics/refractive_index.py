"""Complex refractive indices of smoke materials, tabulated against wavelength.

Both defaults come from OPAC (Hess, Koepke & Schult 1998, "Optical Properties of Aerosols and
Clouds: The Software Package OPAC", Bull. Amer. Meteor. Soc. 79, 831-844), whose component
tables go back to Shettle & Fenn (1979, AFGL-TR-79-0214). Values are for dry particles (0% RH),
0.25-40 µm, as distributed with OPAC (and, unchanged, in ECMWF's ecaeropt `data/refr_idx`).

- SOOT: OPAC "soot" (absorbing black carbon).
- WATER_SOLUBLE: OPAC "water-soluble" (WASO), the standard stand-in for organic / sulphate
  accumulation-mode aerosol. Its 8-10 µm absorption band is what makes organic smoke weakly
  absorbing in the LWIR; in the visible it is almost non-absorbing (k ~ 0.006).

Convention: m = n + i·k with k >= 0 for absorbing media (Bohren & Huffman).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class RefractiveIndexTable:
    """Tabulated n and k against wavelength, interpolated linearly in wavelength.

    Calling it outside the tabulated range raises ValueError rather than extrapolating.
    """

    wavelength_um: np.ndarray
    n: np.ndarray
    k: np.ndarray
    source: str

    def __post_init__(self) -> None:
        arrays = [np.asarray(a, dtype=np.float64) for a in (self.wavelength_um, self.n, self.k)]
        if any(a.ndim != 1 or a.shape != arrays[0].shape for a in arrays) or arrays[0].size < 2:
            raise ValueError("wavelength_um, n and k must be 1-D arrays of equal length >= 2")
        if not np.all(np.diff(arrays[0]) > 0):
            raise ValueError("wavelength_um must be strictly increasing")
        if np.any(arrays[1] <= 0) or np.any(arrays[2] < 0):
            raise ValueError("need n > 0 and k >= 0 (m = n + ik convention)")
        for name, a in zip(("wavelength_um", "n", "k"), arrays):
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def __call__(self, wavelength_um: float | np.ndarray) -> np.ndarray:
        """Complex refractive index n + ik at the given wavelengths (µm)."""
        lam = np.asarray(wavelength_um, dtype=np.float64)
        lo, hi = self.wavelength_um[0], self.wavelength_um[-1]
        if not np.all(np.isfinite(lam)) or np.any(lam < lo) or np.any(lam > hi):
            raise ValueError(
                f"wavelength_um outside the refractive-index table [{lo}, {hi}] µm ({self.source})"
            )
        n = np.interp(lam, self.wavelength_um, self.n)
        k = np.interp(lam, self.wavelength_um, self.k)
        return n + 1j * k


_OPAC_WAVELENGTH_UM = np.array([
    0.25, 0.30, 0.35, 0.40, 0.45, 0.50, 0.55, 0.60, 0.65, 0.70, 0.75, 0.80, 0.90, 1.00, 1.25,
    1.50, 1.75, 2.00, 2.50, 3.00, 3.20, 3.39, 3.50, 3.75, 4.00, 4.50, 5.00, 5.50, 6.00, 6.20,
    6.50, 7.20, 7.90, 8.20, 8.50, 8.70, 9.00, 9.20, 9.50, 9.80, 10.0, 10.6, 11.0, 11.5, 12.5,
    13.0, 14.0, 14.8, 15.0, 16.4, 17.2, 18.0, 18.5, 20.0, 21.3, 22.5, 25.0, 27.9, 30.0, 35.0,
    40.0,
])

SOOT = RefractiveIndexTable(
    wavelength_um=_OPAC_WAVELENGTH_UM,
    n=np.array([
        1.62, 1.74, 1.75, 1.75, 1.75, 1.75, 1.75, 1.75, 1.75, 1.75, 1.75, 1.75, 1.75, 1.76, 1.76,
        1.77, 1.79, 1.80, 1.82, 1.84, 1.86, 1.87, 1.88, 1.90, 1.92, 1.94, 1.97, 1.99, 2.02, 2.03,
        2.04, 2.06, 2.12, 2.13, 2.15, 2.16, 2.17, 2.18, 2.19, 2.20, 2.21, 2.22, 2.23, 2.24, 2.27,
        2.28, 2.31, 2.33, 2.33, 2.36, 2.38, 2.40, 2.41, 2.45, 2.46, 2.48, 2.51, 2.54, 2.57, 2.63,
        2.69,
    ]),
    k=np.array([
        0.45, 0.47, 0.465, 0.46, 0.455, 0.45, 0.44, 0.435, 0.435, 0.43, 0.43, 0.43, 0.435, 0.44,
        0.45, 0.46, 0.48, 0.49, 0.51, 0.54, 0.54, 0.5495, 0.56, 0.57, 0.58, 0.59, 0.60, 0.61,
        0.62, 0.625, 0.63, 0.65, 0.67, 0.68, 0.69, 0.69, 0.70, 0.70, 0.71, 0.715, 0.72, 0.73,
        0.73, 0.74, 0.75, 0.76, 0.775, 0.79, 0.79, 0.81, 0.82, 0.825, 0.83, 0.85, 0.86, 0.87,
        0.89, 0.91, 0.93, 0.97, 1.00,
    ]),
    source="OPAC soot, Hess et al. (1998) after Shettle & Fenn (1979)",
)

WATER_SOLUBLE = RefractiveIndexTable(
    wavelength_um=_OPAC_WAVELENGTH_UM,
    n=np.array([
        1.53, 1.53, 1.53, 1.53, 1.53, 1.53, 1.53, 1.53, 1.53, 1.53, 1.53, 1.52, 1.52, 1.52, 1.51,
        1.51, 1.47, 1.42, 1.42, 1.42, 1.43, 1.43, 1.45, 1.452, 1.455, 1.46, 1.45, 1.44, 1.41,
        1.43, 1.46, 1.40, 1.20, 1.01, 1.30, 2.40, 2.56, 2.20, 1.95, 1.87, 1.82, 1.76, 1.72, 1.67,
        1.62, 1.62, 1.56, 1.44, 1.42, 1.75, 2.08, 1.98, 1.85, 2.12, 2.06, 2.00, 1.88, 1.84, 1.82,
        1.92, 1.86,
    ]),
    k=np.array([
        3.0e-2, 8.0e-3, 5.0e-3, 5.0e-3, 5.0e-3, 5.0e-3, 6.0e-3, 6.0e-3, 7.0e-3, 7.0e-3, 8.5e-3,
        1.0e-2, 1.3e-2, 1.55e-2, 1.9e-2, 2.25e-2, 1.75e-2, 8.0e-3, 1.2e-2, 2.2e-2, 8.0e-3,
        7.05e-3, 5.0e-3, 4.0e-3, 5.0e-3, 1.3e-2, 1.2e-2, 1.8e-2, 2.3e-2, 2.7e-2, 3.3e-2, 7.0e-2,
        6.5e-2, 1.0e-1, 2.15e-1, 2.9e-1, 3.7e-1, 4.2e-1, 1.6e-1, 9.5e-2, 9.0e-2, 7.0e-2, 5.0e-2,
        4.7e-2, 5.3e-2, 5.5e-2, 7.3e-2, 1.0e-1, 2.0e-1, 1.6e-1, 2.42e-1, 1.8e-1, 1.7e-1, 2.2e-1,
        2.3e-1, 2.4e-1, 2.8e-1, 2.9e-1, 3.0e-1, 4.0e-1, 5.0e-1,
    ]),
    source="OPAC water-soluble (WASO, 0% RH), Hess et al. (1998) after Shettle & Fenn (1979)",
)
