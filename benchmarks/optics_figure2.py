"""SmokeSeer Figure 2 analogue: smoke scattering and extinction against wavelength, 0.3-14 µm.

Mie theory over each population's lognormal size distribution (generator.optics.mie), per
unit particle volume fraction, log axes, with the visible and 8-14 µm bands shaded. Also
prints the band-averaged numbers the generator uses.

Writes benchmarks/results/optics_figure2.{csv,png}. Run: python benchmarks/optics_figure2.py
"""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from generator.optics.mie import ORGANIC_SMOKE, SOOT, smoke_optics, spectral_coefficients  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    lam = np.geomspace(0.3, 14.0, 160)
    curves = {pop.name: spectral_coefficients(pop, lam) for pop in (ORGANIC_SMOKE, SOOT)}
    band = {pop.name: smoke_optics(pop) for pop in (ORGANIC_SMOKE, SOOT)}

    with open(RESULTS / "optics_figure2.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        header = ["wavelength_um"]
        for name in curves:
            header += [f"{name}_extinction_per_m", f"{name}_scattering_per_m", f"{name}_asymmetry"]
        writer.writerow(header)
        for i, wl in enumerate(lam):
            row: list[float] = [wl]
            for c in curves.values():
                row += [c.extinction[i], c.scattering[i], c.asymmetry[i]]
            writer.writerow(row)

    fig, ax = plt.subplots(figsize=(7.5, 5))
    ax.axvspan(0.38, 0.78, color="gold", alpha=0.15, label="visible (RGB)")
    ax.axvspan(8.0, 14.0, color="tab:red", alpha=0.08, label="LWIR 8-14 µm")
    styles = {ORGANIC_SMOKE.name: "tab:blue", SOOT.name: "black"}
    for name, c in curves.items():
        ax.loglog(c.wavelength_um, c.scattering, "-", color=styles[name], label=f"{name}: scattering")
        ax.loglog(c.wavelength_um, c.extinction, "--", color=styles[name], label=f"{name}: extinction")
    for k, (name, o) in enumerate(band.items()):
        ax.annotate(f"{name}: band σ_LWIR / σ_vis = {o.ratio_lwir_over_visible:.3f}",
                    xy=(10.0, o.extinction_lwir), xytext=(0.9, 60.0 / 4**k),
                    fontsize=8, color=styles[name], arrowprops={"arrowstyle": "->", "color": styles[name]})
    ax.set(xlabel="wavelength (µm)", ylabel="coefficient per unit particle volume fraction (1/m)",
           title="Smoke optics from Mie theory (lognormal populations)")
    ax.set_xlim(0.3, 14.0)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(RESULTS / "optics_figure2.png", dpi=130)

    for name, o in band.items():
        print(f"{name}: ratio σ_LWIR/σ_vis = {o.ratio_lwir_over_visible:.4f}, "
              f"extinction_rgb = {np.array2string(o.extinction_rgb, precision=4)} 1/m, "
              f"albedo_rgb = {np.array2string(o.albedo_rgb, precision=4)}, "
              f"LWIR albedo = {o.albedo_lwir:.2e}, g_vis = {o.asymmetry_visible:.3f}")
        sca = curves[name].scattering
        print(f"   scattering 0.55 µm / 10 µm = {np.interp(0.55, lam, sca) / np.interp(10.0, lam, sca):.3g}")


if __name__ == "__main__":
    main()
