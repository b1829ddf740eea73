"""generate-scene on 2 cores: seconds per frame per pass, bake time, and the two
accuracy-for-time knobs: Cycles samples (error against a high-sample reference) and
Mantaflow resolution (bake time).

    python benchmarks/generate.py [--quick]

Writes benchmarks/results/generate_{passes,samples,simres}.csv and generate.png.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from contracts.atomic import write_rows_csv  # noqa: E402
from generator.api import generate  # noqa: E402
from contracts.imageio import read_png  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def _run(tmp: Path, name: str, **overrides: object) -> tuple[Path, dict]:
    out = generate("demo", tmp / name, show_progress=False, force=True, **overrides)
    return out, json.loads((out / "dataset.json").read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer sample counts and resolutions")
    args = parser.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    samples = [1, 4, 16, 64] if args.quick else [1, 2, 4, 8, 16, 32, 64, 128]
    reference_spp = 256 if args.quick else 1024
    sim_res = [16, 24, 32] if args.quick else [16, 24, 32, 48, 64]
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        _, meta = _run(tmp, "passes")
        timing = meta["timings_s"]
        pass_rows = [{"step": k, "seconds": round(v, 4), "per": "frame"} for k, v in timing["render"].items()]
        pass_rows.append({"step": "bake", "seconds": round(timing["bake"], 3), "per": "scene"})
        pass_rows.append({"step": "total", "seconds": round(timing["total"], 3), "per": "scene"})
        write_rows_csv(RESULTS / "generate_passes.csv", pass_rows)
        for row in pass_rows:
            print(f"  {row['step']:<22} {row['seconds']:8.3f} s per {row['per']}")

        ref_dir, _ = _run(tmp, "ref", frames=1, passes="rgb.smoky", samples=reference_spp)
        reference = read_png(ref_dir / "rgb/smoky/0000.png").astype(np.float64) / 255
        sample_rows = []
        for spp in samples:
            out, m = _run(tmp, f"spp{spp}", frames=1, passes="rgb.smoky", samples=spp)
            image = read_png(out / "rgb/smoky/0000.png").astype(np.float64) / 255
            rmse = float(np.sqrt(np.mean((image - reference) ** 2)))
            seconds = m["timings_s"]["render"]["rgb.smoky"]
            sample_rows.append({"samples": spp, "seconds_per_frame": round(seconds, 4), "rmse_vs_reference": rmse,
                                "psnr_vs_reference": round(-20 * np.log10(max(rmse, 1e-12)), 2)})
            print(f"  {spp:5d} spp: {seconds:.3f} s/frame, RMSE {rmse:.4f} vs {reference_spp} spp")
        write_rows_csv(RESULTS / "generate_samples.csv", sample_rows)

        sim_rows = []
        for res in sim_res:
            _, m = _run(tmp, f"sim{res}", frames=2, passes="rgb.smoke_alpha", sim_resolution=res)
            sim_rows.append({"sim_resolution": res, "bake_seconds": round(m["timings_s"]["bake"], 3),
                             "rgb_mean_smoke_alpha": round(m["stats"]["rgb_mean_smoke_alpha"], 4)})
            print(f"  sim {res:3d}^3: bake {m['timings_s']['bake']:.2f} s, "
                  f"mean smoke alpha {m['stats']['rgb_mean_smoke_alpha']:.3f}")
        write_rows_csv(RESULTS / "generate_simres.csv", sim_rows)
    base = sample_rows[0]["seconds_per_frame"]
    print("ratios against 1 spp: " + ", ".join(f"{r['samples']} spp ×{r['seconds_per_frame'] / base:.1f}"
                                                for r in sample_rows))
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.loglog([r["seconds_per_frame"] for r in sample_rows], [r["rmse_vs_reference"] for r in sample_rows], "o-")
    for r in sample_rows:
        ax1.annotate(f"{r['samples']} spp", (r["seconds_per_frame"], r["rmse_vs_reference"]), fontsize=8)
    ax1.set_xlabel("render seconds per RGB frame (demo, 64×48, 2 cores)")
    ax1.set_ylabel(f"RMSE vs {reference_spp} spp")
    ax1.set_title("Cycles samples: error against time")
    ax2.plot([r["sim_resolution"] for r in sim_rows], [r["bake_seconds"] for r in sim_rows], "o-")
    ax2.set_xlabel("Mantaflow resolution (voxels, longest side)")
    ax2.set_ylabel("bake seconds (demo timeline)")
    ax2.set_title("Simulation resolution: bake time")
    fig.tight_layout()
    fig.savefig(RESULTS / "generate.png", dpi=120)
    print(f"wrote {RESULTS / 'generate.png'}")


if __name__ == "__main__":
    main()
