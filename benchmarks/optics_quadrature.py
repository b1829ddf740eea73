"""Band-radiance quadrature: error against node count and run time.

Reference: the closed-form series ∫_a^∞ u³/(eᵘ−1) du = Σₙ e^(−na)(a³/n + 3a²/n² + 6a/n³ + 6/n⁴)
(Widger & Woodall 1976) with colour-science's c1, c2. Compared rules:

- project: composite Gauss-Legendre in u = c2/(λT), panels <= 4 wide, k nodes per panel;
- naive: one Gauss-Legendre rule in wavelength over 8-14 µm with n nodes;
- scipy.integrate.quad (adaptive) in wavelength, as the usual baseline.

Writes benchmarks/results/optics_quadrature.{csv,png}. Run: python benchmarks/optics_quadrature.py
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from colour.colorimetry import planck_law  # noqa: E402
from colour.colorimetry.blackbody import CONSTANT_C1, CONSTANT_C2  # noqa: E402
from scipy.integrate import quad  # noqa: E402

from contracts.atomic import write_rows_csv  # noqa: E402
from generator.optics.planck import LWIR_BAND_M, PlanckQuadrature, band_radiance  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
TEMPS = np.array([5.0, 20.0, 50.0, 100.0, 200.0, 300.0, 500.0, 1000.0, 2000.0, 5000.0])
SCENE = np.random.default_rng(0).uniform(250.0, 400.0, 100_000)


def series_band(t: float) -> float:
    def tail(a: float) -> float:
        n = np.arange(1, 20001, dtype=np.float64)
        return float(np.sum(np.exp(-n * a) * (a**3 / n + 3 * a**2 / n**2 + 6 * a / n**3 + 6 / n**4)))

    lo, hi = LWIR_BAND_M
    scale = CONSTANT_C1 / np.pi * (t / CONSTANT_C2) ** 4
    return scale * (tail(CONSTANT_C2 / (hi * t)) - tail(CONSTANT_C2 / (lo * t)))


def naive_lambda_rule(t: np.ndarray, n: int) -> np.ndarray:
    x, w = np.polynomial.legendre.leggauss(n)
    lo, hi = LWIR_BAND_M
    lam = 0.5 * (hi - lo) * x + 0.5 * (hi + lo)
    with np.errstate(over="ignore"):
        spectral = np.asarray(planck_law(lam, t), dtype=np.float64).reshape(n, -1)
    return 0.5 * (hi - lo) * (w @ spectral)


def best_time(fn, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    ref = np.array([series_band(t) for t in TEMPS])
    rows: list[dict[str, object]] = []
    for k in range(1, 13):
        rule = PlanckQuadrature(nodes_per_panel=k)
        err = np.abs(band_radiance(TEMPS, quadrature=rule) / ref - 1)
        seconds = best_time(lambda: band_radiance(SCENE, quadrature=rule))
        rows.append({"method": "project_u_composite_GL", "param": k, "points_300K": k,
                     "points_20K": k * int(np.ceil(min(64.0, CONSTANT_C2 / 20 * (1 / 8e-6 - 1 / 14e-6)) / 4)),
                     "err_300K": err[TEMPS == 300][0], "err_20K": err[TEMPS == 20][0],
                     "err_max": err.max(), "us_per_temperature": 1e6 * seconds / SCENE.size})
    for n in (2, 4, 6, 8, 12, 16, 24, 32, 48, 64):
        with np.errstate(divide="ignore"):
            err = np.abs(naive_lambda_rule(TEMPS, n) / ref - 1)
        seconds = best_time(lambda: naive_lambda_rule(SCENE[:20000], n))
        rows.append({"method": "naive_lambda_GL", "param": n, "points_300K": n, "points_20K": n,
                     "err_300K": err[TEMPS == 300][0], "err_20K": err[TEMPS == 20][0],
                     "err_max": err.max(), "us_per_temperature": 1e6 * seconds / 20000})
    quad_err, quad_time = [], []
    for t, r in zip(TEMPS, ref):
        start = time.perf_counter()
        val, _ = quad(lambda lam: float(planck_law(lam, t)), *LWIR_BAND_M, epsabs=0, epsrel=1e-10)
        quad_time.append(time.perf_counter() - start)
        quad_err.append(abs(val / r - 1))
    rows.append({"method": "scipy_quad", "param": "epsrel=1e-10", "points_300K": "", "points_20K": "",
                 "err_300K": quad_err[5], "err_20K": quad_err[1], "err_max": max(quad_err),
                 "us_per_temperature": 1e6 * float(np.mean(quad_time))})

    write_rows_csv(RESULTS / "optics_quadrature.csv", rows)

    floor = 1e-17
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for method, marker in (("project_u_composite_GL", "o"), ("naive_lambda_GL", "s")):
        sel = [r for r in rows if r["method"] == method]
        pts = [r["points_300K"] for r in sel]
        axes[0].semilogy(pts, [max(r["err_300K"], floor) for r in sel], marker + "-", label=f"{method} 300 K")
        axes[0].semilogy(pts, [max(r["err_max"], floor) for r in sel], marker + "--",
                         label=f"{method} worst of 5-5000 K")
        axes[1].loglog([r["us_per_temperature"] for r in sel], [max(r["err_max"], floor) for r in sel],
                       marker + "-", label=method)
    q = rows[-1]
    axes[1].loglog([q["us_per_temperature"]], [max(q["err_max"], floor)], "k*", ms=12, label="scipy quad")
    axes[0].set(xlabel="quadrature points (per panel for the project rule)", ylabel="relative error",
                title="8-14 µm band radiance: error vs points")
    axes[1].set(xlabel="µs per temperature (vector of 1e5 scene temperatures)",
                ylabel="worst relative error, 5-5000 K", title="error vs run time")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / "optics_quadrature.png", dpi=120)
    for r in rows:
        print(f"{r['method']:24s} {str(r['param']):>14s}  err300={r['err_300K']:.2e}  "
              f"err20={r['err_20K']:.2e}  worst={r['err_max']:.2e}  {r['us_per_temperature']:.3f} µs/T")


if __name__ == "__main__":
    main()
