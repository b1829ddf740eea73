"""The `bench` profile's noise figure: smoky RGB and thermal error inside the smoke mask, at the
profile's own settings (denoised), against a high-sample render of the same scene and seed.

    python benchmarks/generate_bench_noise.py [--scenes chair,house,...] [--frames 2] [--reference-spp 512]

Each scene renders its first `--frames` RGB frames (and the thermal frames in that span) at
the bench profile's size; the reference differs only in samples (both cameras) and has no
denoising. Errors as in benchmarks/generate_denoise.py; the thermal error is also given over
the whole frame, since thin LWIR smoke often stays under the mask threshold (an empty mask
gives nan, not a substitute). Writes
benchmarks/results/generate_bench_noise.csv.
"""
from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from contracts.atomic import write_rows_csv
from generate_denoise import PASSES, load_images, masked_rmse, run
from generator.api import resolve_spec
from generator.optics.planck import band_radiance, band_radiance_derivative
from generator.pipeline import sensor_for
from generator.profiles import BENCHMARK_SCENES, PROFILES
from generator.spec import SceneSpec, parse_passes

RESULTS = Path(__file__).resolve().parent / "results"


def bench_spec(scene: str, frames: int) -> SceneSpec:
    spec, _ = resolve_spec(scene, PROFILES["bench"].overrides)
    return replace(spec, frames=frames, passes=parse_passes(PASSES, "benchmark"))


def reference_of(spec: SceneSpec, spp: int) -> SceneSpec:
    rig = spec.rig
    return replace(spec, rig=replace(rig, rgb=replace(rig.rgb, samples=spp, denoise="none"),
                                     thermal=replace(rig.thermal, samples=spp, denoise="none")))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="chair,house,room", help=f"comma-separated subset of {BENCHMARK_SCENES}")
    parser.add_argument("--frames", type=int, default=2, help="RGB frames per scene (from the first)")
    parser.add_argument("--reference-spp", type=int, default=512, help="samples of the reference render")
    parser.add_argument("--keep", type=Path, help="keep the renders here; finished ones of the same spec are reused")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = args.keep or Path(tmp_name)
        for scene in args.scenes.split(","):
            spec = bench_spec(scene, args.frames)
            sensor = sensor_for(spec).config
            span = float(band_radiance(sensor.t_max_k) - band_radiance(sensor.t_min_k))
            per_kelvin = float(band_radiance_derivative(300.0))
            bench_dir, meta, _ = run(spec, tmp / scene / "bench", reuse=args.keep is not None)
            ref_dir, _, ref_wall = run(reference_of(spec, args.reference_spp), tmp / scene / "reference", reuse=True)
            ref, got = load_images(ref_dir), load_images(bench_dir)
            rgb_masks = [a > spec.smoke.mask_threshold for a in ref["rgb_alpha"]]
            thermal_masks = [a > spec.smoke.mask_threshold for a in ref["thermal_alpha"]]
            thermal = masked_rmse(got["thermal"], ref["thermal"], thermal_masks)
            everywhere = [np.ones_like(m) for m in thermal_masks]
            thermal_frame = masked_rmse(got["thermal"], ref["thermal"], everywhere)
            rows.append({
                "scene": scene, "frames": args.frames, "rgb_samples": spec.rig.rgb.samples,
                "thermal_samples": spec.rig.thermal.samples, "denoise": spec.rig.rgb.denoise,
                "rgb_mask_fraction": round(float(np.mean([m.mean() for m in rgb_masks])), 3),
                "rgb_rmse_in_mask": round(masked_rmse(got["rgb"], ref["rgb"], rgb_masks), 5),
                "thermal_rmse_in_mask_of_span": round(thermal / span, 6),
                "thermal_mask_fraction": round(float(np.mean([m.mean() for m in thermal_masks])), 3),
                "thermal_rmse_in_mask_mk": round(1000 * thermal / per_kelvin, 1),
                "thermal_rmse_whole_frame_mk": round(1000 * thermal_frame / per_kelvin, 1),
                "rgb_smoky_s_per_frame": round(meta["timings_s"]["render"]["rgb.smoky"], 3),
                "thermal_smoky_s_per_frame": round(meta["timings_s"]["render"]["thermal.smoky"], 3),
                "reference_wall_s": round(ref_wall, 1),
            })
            print("  " + ", ".join(f"{k} {v}" for k, v in rows[-1].items()), flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_rows_csv(RESULTS / "generate_bench_noise.csv", rows)
    print(f"wrote {RESULTS / 'generate_bench_noise.csv'}")


if __name__ == "__main__":
    main()
