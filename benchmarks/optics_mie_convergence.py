"""Convergence of the size-distribution integral and of the band averages, against run time.

Part 1 (size integral, per wavelength): the project's trapezoid rule in ln r (±6σ, n nodes) and,
for comparison, Gauss-Hermite with n <= 64 nodes, against a 4001-node trapezoid over ±8σ.
Part 2 (band optics): smoke_optics(n_wavelengths=...) at the default n_radii against a
161-wavelength run: worst relative error of the RGB extinction, albedo and LWIR/visible ratio.

Writes benchmarks/results/optics_mie_convergence.{csv,png}.
Run: python benchmarks/optics_mie_convergence.py
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from contracts.atomic import write_rows_csv  # noqa: E402
from generator.optics.mie import (  # noqa: E402
    ORGANIC_SMOKE,
    SOOT,
    ParticlePopulation,
    efficiencies,
    smoke_optics,
    spectral_coefficients,
)

RESULTS = Path(__file__).resolve().parent / "results"
WAVELENGTHS_UM = (0.40, 0.55, 0.70, 10.0)
N_RADII = (8, 12, 16, 24, 32, 48, 64, 96, 128)
N_WAVELENGTHS = (5, 9, 17, 25, 41, 61, 81)


def area_mean_q(pop: ParticlePopulation, lam: float, xi: np.ndarray, w: np.ndarray) -> float:
    s = np.log(pop.geometric_sigma)
    radii = pop.median_radius_um * np.exp(2 * s * s + s * xi)
    qext, _, _ = efficiencies(complex(pop.refractive_index(lam)), 2 * np.pi * radii / lam)
    return float(np.dot(w, qext) / w.sum())


def gauss_hermite(pop: ParticlePopulation, lam: float, n: int) -> float:
    z, w = np.polynomial.hermite.hermgauss(n)
    return area_mean_q(pop, lam, np.sqrt(2.0) * z, w)


def trapezoid(pop: ParticlePopulation, lam: float, n: int, half_width: float) -> float:
    xi = np.linspace(-half_width, half_width, n)
    return area_mean_q(pop, lam, xi, np.exp(-0.5 * xi * xi))


def main() -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, object]] = []
    for pop in (ORGANIC_SMOKE, SOOT):
        for lam in WAVELENGTHS_UM:
            ref = trapezoid(pop, lam, 4001, 8.0)
            for n in N_RADII:
                start = time.perf_counter()
                ours = float(spectral_coefficients(pop, np.array([lam]), n_radii=n).extinction[0])
                elapsed = time.perf_counter() - start
                s = np.log(pop.geometric_sigma)
                ours_q = ours * 4 * pop.median_radius_um * 1e-6 * np.exp(2.5 * s * s) / 3
                rows.append({"part": "size_integral", "population": pop.name, "wavelength_um": lam,
                             "rule": "trapezoid_lnr", "n": n, "rel_error": abs(ours_q / ref - 1),
                             "seconds": elapsed})
                if n > 64:  # its outer nodes reach radii of ~1 mm: minutes of Mie for nothing
                    continue
                start = time.perf_counter()
                gh = gauss_hermite(pop, lam, n)
                rows.append({"part": "size_integral", "population": pop.name, "wavelength_um": lam,
                             "rule": "gauss_hermite", "n": n, "rel_error": abs(gh / ref - 1),
                             "seconds": time.perf_counter() - start})
    for pop in (ORGANIC_SMOKE, SOOT):
        ref = smoke_optics(pop, n_wavelengths=161)
        for n in N_WAVELENGTHS:
            start = time.perf_counter()
            got = smoke_optics(pop, n_wavelengths=n)
            elapsed = time.perf_counter() - start
            rows.append({
                "part": "band_average", "population": pop.name, "wavelength_um": "",
                "rule": "n_wavelengths", "n": n,
                "rel_error": float(max(
                    np.max(np.abs(got.extinction_rgb / ref.extinction_rgb - 1)),
                    np.max(np.abs(got.albedo_rgb / ref.albedo_rgb - 1)),
                    abs(got.ratio_lwir_over_visible / ref.ratio_lwir_over_visible - 1),
                )),
                "seconds": elapsed,
            })

    write_rows_csv(RESULTS / "optics_mie_convergence.csv", rows)

    floor = 1e-12
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.3))
    colors = dict(zip(WAVELENGTHS_UM, ("tab:blue", "tab:green", "tab:red", "tab:gray")))
    for pop, ls in ((ORGANIC_SMOKE, "-"), (SOOT, ":")):
        for lam in WAVELENGTHS_UM:
            for rule, marker in (("trapezoid_lnr", "o"), ("gauss_hermite", "x")):
                sel = [r for r in rows if r["population"] == pop.name and r["wavelength_um"] == lam
                       and r["rule"] == rule]
                label = f"{pop.name} {lam} µm" if rule == "trapezoid_lnr" else None
                axes[0].semilogy([r["n"] for r in sel], [max(r["rel_error"], floor) for r in sel],
                                 marker + ls, color=colors[lam], label=label, alpha=0.9 if marker == "o" else 0.4)
                if rule == "trapezoid_lnr":
                    axes[1].loglog([1e3 * r["seconds"] for r in sel],
                                   [max(r["rel_error"], floor) for r in sel], marker + ls, color=colors[lam])
        sel = [r for r in rows if r["part"] == "band_average" and r["population"] == pop.name]
        axes[2].loglog([r["seconds"] for r in sel], [max(r["rel_error"], floor) for r in sel], "o" + ls,
                       label=pop.name)
        for r in sel:
            axes[2].annotate(str(r["n"]), (r["seconds"], max(r["rel_error"], floor)), fontsize=7)
    axes[0].set(xlabel="size nodes n_radii (o trapezoid in ln r, x Gauss-Hermite)",
                ylabel="relative error of ⟨Q_ext⟩", title="size-distribution integral")
    axes[1].set(xlabel="ms per wavelength (trapezoid rule)", ylabel="relative error",
                title="size integral: error vs time")
    axes[2].set(xlabel="s per smoke_optics call (labels: n_wavelengths)",
                ylabel="worst rel. error (RGB σ, albedo, ratio)", title="band averages, n_radii=64")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=6)
    axes[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(RESULTS / "optics_mie_convergence.png", dpi=120)
    for r in rows:
        print(f"{r['part']:14s} {r['population']:14s} {str(r['wavelength_um']):5s} {r['rule']:14s} "
              f"n={r['n']:4d}  err={r['rel_error']:.2e}  {r['seconds'] * 1e3:9.1f} ms")


if __name__ == "__main__":
    main()
