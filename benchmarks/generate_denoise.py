"""Converged smoke at the lowest cost: error inside the smoke mask against render time, for
Cycles samples, OpenImageDenoise guides and the volume step rate, on the demo preset.

    python benchmarks/generate_denoise.py [--frames N] [--reference-spp 512] [--keep DIR]

Every option renders the demo's smoky RGB and smoky thermal images (plus the smoke alpha that
defines the mask); the reference is the same spec and seed at `--reference-spp` samples for
both cameras, not denoised. RGB error is RMSE of the 8-bit image scaled to [0, 1]; thermal
error is RMSE of the radiance divided by the sensor's radiance span (so [0, 1] too) and, for
scale, in millikelvin of a 300 K scene (radiance / dL/dT). Both only inside the reference's
smoke mask. Writes benchmarks/results/generate_denoise.{csv,png}.
"""
from __future__ import annotations

import argparse
import csv
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from contracts.atomic import write_rows_csv  # noqa: E402
from contracts.imageio import read_exr_channel, read_png  # noqa: E402
from generator.api import resolve_spec  # noqa: E402
from generator.optics.planck import band_radiance, band_radiance_derivative  # noqa: E402
from generator.pipeline import generate, sensor_for  # noqa: E402
from generator.spec import SceneSpec, parse_passes  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
PASSES = "rgb.smoky,rgb.smoke_alpha,thermal.smoky,thermal.smoke_alpha"
#: (label, rgb samples, thermal samples, denoise, volume step rate)
OPTIONS = [
    *[(f"{s} spp", s, max(1, s // 2), "none", 1.0) for s in (4, 16, 64)],
    *[(f"{s} spp + OIDN", s, max(1, s // 2), "color", 1.0) for s in (4, 16, 32)],
    *[(f"{s} spp + OIDN albedo", s, max(1, s // 2), "albedo", 1.0) for s in (16, 32)],
    *[(f"{s} spp + OIDN albedo+normal", s, max(1, s // 2), "albedo_normal", 1.0) for s in (4, 8, 16, 32, 64)],
    *[(f"32 spp + OIDN a+n, step x{r:g}", 32, 16, "albedo_normal", r) for r in (0.5, 2.0, 4.0)],
]


def configured(spec: SceneSpec, frames: int, rgb_spp: int, thermal_spp: int, denoise: str, step: float) -> SceneSpec:
    rig = spec.rig
    rgb = replace(rig.rgb, samples=rgb_spp, denoise=denoise, volume_step_rate=step)
    thermal = replace(rig.thermal, samples=thermal_spp, denoise=denoise, volume_step_rate=step)
    return replace(spec, frames=frames, passes=parse_passes(PASSES, "benchmark"),
                   rig=replace(rig, rgb=rgb, thermal=thermal))


def load_images(root: Path) -> dict[str, list[np.ndarray]]:
    stems = {m: [f["file_stem"] for f in json.loads((root / f"transforms_{m}.json").read_text())["frames"]]
             for m in ("rgb", "thermal")}
    return {
        "rgb": [read_png(root / "rgb/smoky" / f"{s}.png").astype(np.float64) / 255 for s in stems["rgb"]],
        "rgb_alpha": [read_exr_channel(root / "rgb/smoke_alpha" / f"{s}.exr", "A") for s in stems["rgb"]],
        "thermal": [read_exr_channel(root / "thermal/smoky_radiance" / f"{s}.exr", "L").astype(np.float64)
                    for s in stems["thermal"]],
        "thermal_alpha": [read_exr_channel(root / "thermal/smoke_alpha" / f"{s}.exr", "A") for s in stems["thermal"]],
    }


def masked_rmse(images: list[np.ndarray], references: list[np.ndarray], masks: list[np.ndarray]) -> float:
    errors = [((a - b) ** 2)[m] for a, b, m in zip(images, references, masks)]
    flat = np.concatenate([e.reshape(-1) for e in errors])
    return float(np.sqrt(flat.mean())) if flat.size else float("nan")


def run(spec: SceneSpec, out: Path, reuse: bool = False) -> tuple[Path, dict, float]:
    """Generate `spec` at `out`; with `reuse`, a finished dataset of the same spec is kept (wall 0)."""
    previous = out / "dataset.json"
    if reuse and previous.exists() and json.loads(previous.read_text())["spec_sha256"] == spec.sha256():
        print(f"reusing {out}")
        return out, json.loads(previous.read_text()), 0.0
    t0 = time.perf_counter()
    generate(spec, out, show_progress=False, force=True)
    return out, json.loads((out / "dataset.json").read_text()), time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=6, help="RGB frames of the demo to render (default: all 6)")
    parser.add_argument("--reference-spp", type=int, default=512, help="samples of the reference render")
    parser.add_argument("--plot-only", action="store_true", help="redraw the PNG from the CSV and exit")
    parser.add_argument("--keep", type=Path,
                        help="keep the renders here and reuse any finished one of the same spec (delete to redo)")
    args = parser.parse_args()
    if args.plot_only:
        plot_from_csv(args.reference_spp)
        return
    base, _ = resolve_spec("demo")
    sensor = sensor_for(base).config
    span = float(band_radiance(sensor.t_max_k) - band_radiance(sensor.t_min_k))
    per_kelvin = float(band_radiance_derivative(300.0))
    rows = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = args.keep or Path(tmp_name)
        ref_spec = configured(base, args.frames, args.reference_spp, args.reference_spp, "none", 1.0)
        ref_dir, _, ref_wall = run(ref_spec, tmp / "reference", reuse=True)
        ref = load_images(ref_dir)
        rgb_masks = [a > base.smoke.mask_threshold for a in ref["rgb_alpha"]]
        thermal_masks = [a > base.smoke.mask_threshold for a in ref["thermal_alpha"]]
        print(f"reference: {args.reference_spp} spp in {ref_wall:.0f} s; mask covers "
              f"{np.mean([m.mean() for m in rgb_masks]):.2f} (RGB), {np.mean([m.mean() for m in thermal_masks]):.2f} "
              f"(thermal) of the pixels")
        for i, (label, rgb_spp, thermal_spp, denoise, step) in enumerate(OPTIONS):
            out, meta, _ = run(configured(base, args.frames, rgb_spp, thermal_spp, denoise, step), tmp / f"o{i}",
                                  reuse=args.keep is not None)
            images = load_images(out)
            render = meta["timings_s"]["render"]
            thermal_rmse = masked_rmse(images["thermal"], ref["thermal"], thermal_masks)
            rows.append({
                "option": label, "rgb_samples": rgb_spp, "thermal_samples": thermal_spp, "denoise": denoise,
                "volume_step_rate": step,
                "rgb_rmse_in_mask": round(masked_rmse(images["rgb"], ref["rgb"], rgb_masks), 5),
                "thermal_rmse_in_mask_of_span": round(thermal_rmse / span, 6),
                "thermal_rmse_in_mask_mk": round(1000 * thermal_rmse / per_kelvin, 2),
                "rgb_smoky_s_per_frame": round(render["rgb.smoky"], 4),
                "thermal_smoky_s_per_frame": round(render["thermal.smoky"], 4),
                "generate_total_s": round(meta["timings_s"]["total"], 2),
            })
            print("  " + ", ".join(f"{k} {v}" for k, v in rows[-1].items()), flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_rows_csv(RESULTS / "generate_denoise.csv", rows)
    reference = next(r for r in rows if r["option"] == "16 spp")
    print("time ratios against 16 spp without denoising (RGB smoky): " + ", ".join(
        f"{r['option']} x{r['rgb_smoky_s_per_frame'] / reference['rgb_smoky_s_per_frame']:.2f}" for r in rows))
    plot(rows, args.reference_spp)


def plot(rows: list[dict], reference_spp: int) -> None:
    """Error against render time (top; per-frame times swing with the machine's load) and
    against samples (bottom; the load-independent cost)."""
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    for col, (modality, err_key, err_label) in enumerate((
            ("rgb", "rgb_rmse_in_mask", "RGB RMSE in smoke mask ([0,1] pixels)"),
            ("thermal", "thermal_rmse_in_mask_mk", "thermal RMSE in smoke mask (mK at 300 K)"))):
        for row, (x_key, x_label) in enumerate(((f"{modality}_smoky_s_per_frame",
                                                 f"{modality} smoky render seconds per frame (demo, 2 cores)"),
                                                (f"{modality}_samples", f"{modality} Cycles samples per pixel"))):
            ax = axes[row][col]
            for denoise, marker in (("none", "o"), ("color", "s"), ("albedo", "^"), ("albedo_normal", "D")):
                sel = sorted((r for r in rows if r["denoise"] == denoise and float(r["volume_step_rate"]) == 1.0),
                             key=lambda r: float(r[x_key]))
                if sel:
                    ax.loglog([float(r[x_key]) for r in sel], [float(r[err_key]) for r in sel],
                              marker=marker, label=f"denoise: {denoise}")
            for r in rows:
                ax.annotate(r["option"], (float(r[x_key]), float(r[err_key])), fontsize=6)
            if modality == "rgb":
                ax.axhline(0.02, color="grey", linestyle="--", linewidth=0.8, label="must hold: 0.02")
            ax.set_xlabel(x_label)
            ax.set_ylabel(err_label)
            ax.set_title(f"{modality}: error against the {reference_spp}-spp reference")
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / "generate_denoise.png", dpi=110)
    print(f"wrote {RESULTS / 'generate_denoise.png'}")


def plot_from_csv(reference_spp: int) -> None:
    with (RESULTS / "generate_denoise.csv").open() as fh:
        plot(list(csv.DictReader(fh)), reference_spp)


if __name__ == "__main__":
    main()
