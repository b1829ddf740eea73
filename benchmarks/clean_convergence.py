"""Converged clean ground truth: how far the smoke-free passes lie from a render with 4x the
samples, and what they cost, for a ladder of `clean_samples` (issue 49, item 5).

    python benchmarks/clean_convergence.py [--scenes demo,room] [--samples 4,8,...,1024] [--frames 2]
                                           [--keep DIR]

Rows already in the CSV for other (scene, RGB frames) pairs are kept, so the ladders of different
scenes can be measured in separate runs (docs/generator.md gives the commands).

Each scene renders only its clean passes (RGB clean, thermal clean radiance) at every rung of the
ladder, with the same seed. The demo is rendered at its preset size, any other scene at the
`standard` profile's size. The clean passes never show smoke, so the generator builds no smoke
domain and bakes nothing (`generator.job.shows_smoke`); the surfaces, lights and cameras are
the preset's. RGB PSNR is
taken on the 8-bit PNGs a dataset holds; thermal PSNR on the clean radiance at the sensor's
resolution, with the sensor's radiance span (L_band(t_max) - L_band(t_min)) as the peak. Each
rung is compared with the rung of 4x its samples (and with the top rung). Writes
benchmarks/results/generate_clean_convergence.{csv,png}.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
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
from generator.assets import load_manifest  # noqa: E402
from generator.optics.planck import band_radiance  # noqa: E402
from generator.job import resolve_asset_materials  # noqa: E402
from generator.pipeline import generate, sensor_for  # noqa: E402
from generator.profiles import get_profile  # noqa: E402
from generator.spec import Overrides, SceneSpec, parse_passes  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
NAME = "generate_clean_convergence"
TARGET_DB = 45.0
RATIO = 4


def preset_spec(scene: str, frames: int) -> SceneSpec:
    """The demo at its preset size, any other preset at the standard profile's size."""
    overrides = Overrides(frames=frames) if scene == "demo" else replace(get_profile("standard").overrides,
                                                                           frames=frames)
    spec, source = resolve_spec(scene, overrides)
    return resolve_asset_materials(spec, load_manifest(), source)  # as the dataset records it, so reuse finds it


def clean_only(spec: SceneSpec, samples: int) -> SceneSpec:
    """`spec` with its clean passes only, both cameras at `samples` clean samples."""
    rig = spec.rig
    return replace(spec, passes=parse_passes("rgb.clean,thermal.clean", "benchmark"),
                   rig=replace(rig, rgb=replace(rig.rgb, clean_samples=samples),
                               thermal=replace(rig.thermal, clean_samples=samples)))


def render(spec: SceneSpec, out: Path, reuse: bool) -> tuple[dict, bool]:
    """dataset.json of `spec` generated at `out`, and whether it was rendered now; with `reuse`,
    a finished one of the same spec is kept."""
    meta_path = out / "dataset.json"
    if reuse and meta_path.exists() and json.loads(meta_path.read_text())["spec_sha256"] == spec.sha256():
        return json.loads(meta_path.read_text()), False
    generate(spec, out, show_progress=False, force=True)
    return json.loads(meta_path.read_text()), True


def images(root: Path) -> dict[str, list[np.ndarray]]:
    stems = {m: [f["file_stem"] for f in json.loads((root / f"transforms_{m}.json").read_text())["frames"]]
             for m in ("rgb", "thermal")}
    return {"rgb": [read_png(root / "rgb/clean" / f"{s}.png").astype(np.float64) / 255 for s in stems["rgb"]],
            "thermal": [read_exr_channel(root / "thermal/clean_radiance" / f"{s}.exr", "L").astype(np.float64)
                        for s in stems["thermal"]]}


def psnr(a: list[np.ndarray], b: list[np.ndarray], peak: float) -> float:
    """Per-frame PSNR, averaged over the frames (the benchmark's convention)."""
    values = [10 * np.log10(peak**2 / max(float(np.mean((x - y) ** 2)), 1e-30)) for x, y in zip(a, b)]
    return float(np.mean(values))


def measure(scene: str, ladder: list[int], frames: int, work: Path, reuse: bool) -> list[dict]:
    spec = preset_spec(scene, frames)
    span = sensor_for(spec).config  # the dataset's sensor span, fire included
    peak = {"rgb": 1.0, "thermal": float(band_radiance(span.t_max_k) - band_radiance(span.t_min_k))}
    renders: dict[int, dict[str, list[np.ndarray]]] = {}
    metas: dict[int, dict] = {}
    loads: dict[int, float] = {}
    for n in ladder:
        t0 = time.perf_counter()
        metas[n], rendered = render(clean_only(spec, n), work / scene / f"s{n}", reuse)
        loads[n] = os.getloadavg()[0] if rendered else float("nan")  # a reused render's load is not known
        renders[n] = images(work / scene / f"s{n}")
        print(f"{scene} {n} samples: {time.perf_counter() - t0:.0f} s (load {loads[n]:.1f})", flush=True)
    top = ladder[-1]
    rows = []
    for n in ladder:
        for modality in ("rgb", "thermal"):
            cam = spec.rig.rgb if modality == "rgb" else spec.rig.thermal

            def db(reference: int) -> float | str:
                """PSNR of this rung against rung `reference`; empty where that was not rendered."""
                if reference not in renders or reference == n:
                    return ""
                return round(psnr(renders[n][modality], renders[reference][modality], peak[modality]), 2)

            rows.append({
                "scene": scene, "modality": modality, "width": cam.width, "height": cam.height,
                "rgb_frames": frames, "frames": len(renders[n][modality]), "clean_samples": n,
                f"psnr_vs_{RATIO}x_db": db(RATIO * n), "psnr_vs_top_db": db(top),
                "top_samples": top,
                "seconds_per_frame": round(metas[n]["timings_s"]["render"][f"{modality}.clean"], 3),
                "load_1min": round(loads[n], 2) if loads[n] == loads[n] else "",
            })
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="demo,room", help="comma-separated presets (default: demo,room)")
    parser.add_argument("--samples", default="4,8,16,32,64,128,256,512,1024", help="the clean_samples ladder")
    parser.add_argument("--frames", type=int, default=2, help="RGB frames per scene (default 2)")
    parser.add_argument("--plot-only", action="store_true", help="redraw the PNG from the CSV and exit")
    parser.add_argument("--keep", type=Path, help="keep the renders here and reuse finished ones of the same spec")
    args = parser.parse_args()
    if args.plot_only:
        with (RESULTS / f"{NAME}.csv").open() as fh:
            plot(list(csv.DictReader(fh)))
        return
    ladder = sorted(int(s) for s in args.samples.split(","))
    rows = []
    with tempfile.TemporaryDirectory() as tmp_name:
        work = args.keep or Path(tmp_name)
        for scene in args.scenes.split(","):
            rows += measure(scene.strip(), ladder, args.frames, work, args.keep is not None)
    for row in rows:
        print("  " + ", ".join(f"{k} {v}" for k, v in row.items()))
    RESULTS.mkdir(parents=True, exist_ok=True)
    rows = kept_rows({(r["scene"], str(r["rgb_frames"])) for r in rows}) + rows
    write_rows_csv(RESULTS / f"{NAME}.csv", rows)
    plot(rows)


def kept_rows(measured: set[tuple[str, str]]) -> list[dict]:
    """Rows of the existing CSV for (scene, RGB frames) pairs this run did not measure: a long
    reference is rendered once, in its own run."""
    path = RESULTS / f"{NAME}.csv"
    if not path.exists():
        return []
    with path.open() as fh:
        return [r for r in csv.DictReader(fh) if (r["scene"], r.get("rgb_frames")) not in measured]


def plot(rows: list[dict]) -> None:
    """PSNR against the 4x render, over samples (left) and over render seconds per frame (right)."""
    key = f"psnr_vs_{RATIO}x_db"
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for scene, frames in dict.fromkeys((r["scene"], str(r["rgb_frames"])) for r in rows):
        for modality, style in (("rgb", "-o"), ("thermal", "--s")):
            pts = [r for r in rows if (r["scene"], str(r["rgb_frames"]), r["modality"]) == (scene, frames, modality)
                   and r[key] != ""]
            if not pts:
                continue
            label = f"{scene} {modality} {pts[0]['width']}x{pts[0]['height']}, {frames} RGB frames"
            samples = [int(r["clean_samples"]) for r in pts]
            seconds = [float(r["seconds_per_frame"]) for r in pts]
            values = [float(r[key]) for r in pts]
            axes[0].plot(samples, values, style, label=label)
            axes[1].plot(seconds, values, style, label=label)
    for ax, xlabel in zip(axes, ("clean samples per pixel", "render seconds per clean frame (2 cores, shared)")):
        ax.axhline(TARGET_DB, color="k", lw=0.8, ls=":")
        ax.set_xscale("log", base=2 if "samples" in xlabel else 10)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(f"PSNR against {RATIO}x the samples (dB)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Clean ground truth: PSNR against a render with 4x the samples (target 45 dB)")
    fig.tight_layout()
    fig.savefig(RESULTS / f"{NAME}.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
