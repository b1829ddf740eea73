"""`generate-benchmark`: generate the ten benchmark scenes at one profile, with evidence.

Each scene goes to OUT/<scene>/ through `generator.api.generate`. A scene whose dataset is
already there and was made from the same resolved spec is skipped (so an interrupted run
resumes; an unfinished scene also resumes inside the generator's own staging folder); one
that differs only in ground truth (the clean passes' samples, or a ground-truth pass it lacks,
such as `rgb.shadowed`) has just that rendered (`generator.ground_truth_refresh`); one made from
another spec is regenerated. With `--clean-from DIR`,
DIR/<scene> provides the clean passes of a scene generated at another density scale
(`generator.clean_reuse`). Every scene prints one line (time, size, smoke statistics), and the run
writes OUT/benchmark.json and OUT/benchmark.md.

Besides the generator's statistics, each record has the mean RGB smoke opacity inside the
smoke (where it exceeds the mask threshold), its target `OPACITY_PER_DENSITY x density`,
and the factor by which the scene's `extinction_per_m` would have to change to meet it:
the calibration that makes "density" mean the same thing in every scene.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from generator.api import generate, resolve_spec
from generator.assets import load_manifest
from generator.ground_truth_refresh import refresh_ground_truth, refresh_plan
from generator.clean_reuse import generate_reusing_clean
from contracts.errors import DatasetError
from generator.errors import GeneratorError
from generator.job import resolve_asset_materials
from generator.optical_depth import dataset_alphas, solve_increasing
from generator.pipeline import made_from
from generator.random_benchmark import run_random_set
from generator.profiles import (
    BENCHMARK_SCENES,
    OPACITY_PER_DENSITY,
    PROFILES,
    Profile,
    get_profile,
    strong_motion,
)
from generator.spec import SceneSpec


def folder_size(path: Path) -> tuple[int, int]:
    """Total bytes and number of files under `path`."""
    files = [p for p in path.rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files), len(files)


def extinction_scale(alphas: np.ndarray, threshold: float, target: float) -> float:
    """Factor k on the extinction that brings the mean opacity inside the smoke to `target`.

    Opacity is 1 - transmittance, so scaling every extinction coefficient by k turns a
    pixel's opacity a into 1 - (1 - a)^k exactly; the mean over the pixels that are smoke
    now (a > threshold) is monotone in k, and bisection on log k solves for it. NaN when
    there is no smoke.
    """
    inside = np.clip(alphas[alphas > threshold].astype(np.float64), 0.0, 1.0 - 1e-9)
    if inside.size == 0 or not 0.0 < target < 1.0:
        return float("nan")
    log_clear = np.log1p(-inside)
    return solve_increasing(lambda k: float(np.mean(-np.expm1(k * log_clear))), target, 1e-3, 1e3)


def _resolved(scene: str, profile: Profile, density_scale: float | None) -> SceneSpec:
    spec, source = resolve_spec(scene, replace(profile.overrides, density_scale=density_scale))
    return resolve_asset_materials(spec, load_manifest(), source)


def run_scene(scene: str, profile: Profile, out_root: Path, force: bool, threads: int | None,
              show_progress: bool, density_scale: float | None, bake_store: Path | None,
              clean_from: Path | None = None) -> dict[str, Any]:
    """Generate (or reuse) one scene; returns its benchmark record. `density_scale` overrides
    the preset's; `bake_store` keeps and reuses the bakes (generator.bakes); `clean_from` is a
    folder whose dataset of the scene provides the clean passes (generator.clean_reuse)."""
    spec = _resolved(scene, profile, density_scale)
    out = out_root / scene
    reused = not force and made_from(out, spec)
    refreshed = not reused and not force and refresh_plan(out, spec) is not None
    started = time.perf_counter()
    if refreshed:
        refresh_ground_truth(out, spec, threads=threads, show_progress=show_progress, bake_store=bake_store)
    elif not reused and clean_from is not None:
        generate_reusing_clean(spec, out, clean_from / scene, threads=threads, show_progress=show_progress,
                               bake_store=bake_store, force=True)
    elif not reused:
        generate(scene, out, force=True, show_progress=show_progress, threads=threads, bake_store=bake_store,
                 density_scale=density_scale, **profile.kwargs())
    wall = time.perf_counter() - started
    status = "reused" if reused else "refreshed" if refreshed else "generated"  # refreshed: ground truth only
    meta = json.loads((out / "dataset.json").read_text())
    size, n_files = folder_size(out)
    frames = {m: len(json.loads((out / f"transforms_{m}.json").read_text())["frames"])
              for m in ("rgb", "thermal") if (out / f"transforms_{m}.json").is_file()}
    alphas = dataset_alphas(out)
    threshold = spec.smoke.mask_threshold
    inside = alphas[alphas > threshold]
    target = OPACITY_PER_DENSITY * spec.smoke.density
    return {
        "scene": scene, "paper_analogue": BENCHMARK_SCENES[scene], "status": status,
        "density": spec.smoke.density, "density_scale": spec.smoke.density_scale, "fire": spec.has_fire,
        "strong_motion": strong_motion(spec),
        "frames": frames, "seconds": wall if status == "generated" else meta["timings_s"]["total"],
        "size_bytes": size, "files": n_files, "stats": meta.get("stats", {}),
        "opacity_in_smoke": float(inside.mean()) if inside.size else None, "target_opacity": target,
        "extinction_scale": extinction_scale(alphas, threshold, target),
        "extinction_per_m": spec.smoke.extinction_per_m, "code_sha256": meta.get("code_sha256"),
        "clean_reused_from": meta.get("clean_reused", {}).get("from"),
    }


def _fmt(value: Any, spec: str) -> str:
    return format(value, spec) if isinstance(value, (int, float)) else "n/a"


def scene_line(r: dict[str, Any]) -> str:
    s = r["stats"]
    return (f"{r['scene']:<11} {r['status']:<9} {r['seconds']:7.1f} s {r['size_bytes'] / 1e6:7.2f} MB  "
            f"density {r['density']:.2f}  opacity in smoke {_fmt(r['opacity_in_smoke'], '.3f')} "
            f"(target {r['target_opacity']:.2f})  rgb alpha {_fmt(s.get('rgb_mean_smoke_alpha'), '.3f')}  "
            f"thermal alpha {_fmt(s.get('thermal_mean_smoke_alpha'), '.4f')}  "
            f"PSNR {_fmt(s.get('psnr_smoky_vs_clean'), '.1f')} dB")


def markdown_table(records: list[dict[str, Any]], profile: Profile) -> str:
    head = ("| scene | paper analogue | density | fire | strong motion | frames RGB/thermal | time (s) | size (MB) "
            "| RGB opacity in smoke (target) | RGB mean smoke alpha | RGB smoke fraction | thermal mean smoke alpha "
            "| PSNR smoky vs clean (dB) |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    rows = []
    for r in records:
        s = r["stats"]
        rows.append(
            f"| {r['scene']} | {r['paper_analogue']} | {r['density']:.2f} | {'yes' if r['fire'] else 'no'} "
            f"| {'yes' if r['strong_motion'] else 'no'} | {r['frames'].get('rgb', 0)}/{r['frames'].get('thermal', 0)} "
            f"| {r['seconds']:.0f} | {r['size_bytes'] / 1e6:.1f} "
            f"| {_fmt(r['opacity_in_smoke'], '.2f')} ({r['target_opacity']:.2f}) "
            f"| {_fmt(s.get('rgb_mean_smoke_alpha'), '.3f')} | {_fmt(s.get('rgb_smoke_fraction'), '.2f')} "
            f"| {_fmt(s.get('thermal_mean_smoke_alpha'), '.4f')} | {_fmt(s.get('psnr_smoky_vs_clean'), '.1f')} |")
    total_s = sum(r["seconds"] for r in records)
    total_mb = sum(r["size_bytes"] for r in records) / 1e6
    scales = sorted({r["density_scale"] for r in records})
    k = "" if scales in ([], [1.0]) else f", density scale {', '.join(f'{v:g}' for v in scales)}"
    return (f"Profile `{profile.name}` ({profile.description}){k}.\n\n" + head + "\n".join(rows)
            + f"\n\nTotal: {total_s:.0f} s, {total_mb:.1f} MB.\n")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="generate-benchmark",
                                description="Generate the ten-scene synthetic smoke benchmark at one profile, "
                                            "or a set of drawn scenes (--random N).")
    p.add_argument("--profile", choices=sorted(PROFILES), help="size profile (docs/benchmark.md)")
    p.add_argument("--random", type=int, metavar="N",
                   help="instead of the ten scenes, N scenes drawn by the scene sampler, named random_SEED, at the "
                        "random sets' size (docs/generator.md, 'The scene sampler')")
    p.add_argument("--seed-base", type=int, default=0, metavar="S", help="with --random: seeds S to S+N-1 (default 0)")
    p.add_argument("--set", action="append", default=[], metavar="AXIS=VALUE",
                   help="with --random: pin a sampler axis in every scene, e.g. fire=false or optical_depth=1:3")
    p.add_argument("--workers", type=int, default=1, metavar="W",
                   help="with --random: scenes generated at once, each rendering with cores/W threads (default 1)")
    p.add_argument("--scheduler", default="local",
                   help="with --random: a Dask scheduler address (tcp://host:8786), or 'local' (default) for a "
                        "LocalCluster of W workers")
    p.add_argument("--out", type=Path, required=True, help="output folder; one dataset per scene inside it")
    p.add_argument("--scenes", help=f"comma-separated subset of: {','.join(BENCHMARK_SCENES)}")
    p.add_argument("--force", action="store_true", help="regenerate scenes that are already finished")
    p.add_argument("--threads", type=int, help="render threads per scene (default: all cores)")
    p.add_argument("--density-scale", type=float, metavar="K",
                   help="scale every smoke coefficient by K in every scene: opacity 1-(1-a)^K, 0 = no smoke")
    p.add_argument("--bake-cache", type=Path, metavar="DIR",
                   help="keep each scene's Mantaflow bake in DIR; a run at another --density-scale only renders")
    p.add_argument("--clean-from", type=Path, metavar="DIR",
                   help="copy each scene's clean passes from DIR/SCENE, the same scene at another --density-scale, "
                        "instead of rendering them")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.random is not None:
        given = [flag for flag, value in (("--profile", args.profile), ("--scenes", args.scenes),
                                          ("--threads", args.threads), ("--density-scale", args.density_scale),
                                          ("--bake-cache", args.bake_cache), ("--clean-from", args.clean_from))
                 if value is not None]
        if given:
            parser.error(f"{', '.join(given)}: not with --random (drawn scenes have their own size; "
                         "--workers sets the threads)")
        if args.random < 1 or args.workers < 1 or args.seed_base < 0:
            parser.error("--random and --workers must be at least 1, --seed-base at least 0")
        return run_random_set(args.random, args.seed_base, args.set, args.out, args.workers, args.scheduler,
                              args.force, args.quiet)
    if args.profile is None:
        parser.error("give --profile NAME (the ten scenes) or --random N (drawn scenes)")
    if args.set:
        parser.error("--set pins the axes of drawn scenes: use it with --random N")
    scenes = list(BENCHMARK_SCENES) if not args.scenes else [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = [s for s in scenes if s not in BENCHMARK_SCENES]
    if unknown:
        print(f"generate-benchmark: error: unknown scene(s) {', '.join(unknown)}; "
              f"choose from {', '.join(BENCHMARK_SCENES)}", file=sys.stderr)
        return 2
    profile = get_profile(args.profile)
    if args.clean_from is not None and not args.clean_from.is_dir():
        print(f"generate-benchmark: error: --clean-from {args.clean_from}: no such folder", file=sys.stderr)
        return 2
    try:  # a bad option is one line before any scene starts, not ten failed scenes
        _resolved(scenes[0], profile, args.density_scale)
    except GeneratorError as exc:
        print(f"generate-benchmark: error: {exc}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    records, failed = [], []
    started = time.perf_counter()
    for scene in scenes:
        try:
            record = run_scene(scene, profile, args.out, args.force, args.threads, not args.quiet,
                               args.density_scale, args.bake_cache, args.clean_from)
        except (GeneratorError, DatasetError) as exc:
            print(f"{scene:<11} FAILED: {exc}", file=sys.stderr)
            failed.append(scene)
            continue
        except KeyboardInterrupt:
            print("generate-benchmark: interrupted; run the same command again to resume", file=sys.stderr)
            return 130
        records.append(record)
        print(scene_line(record), flush=True)
    summary = {
        "profile": profile.name, "description": profile.description, "overrides": profile.kwargs(),
        "density_scale": args.density_scale,
        "scenes": records, "failed": failed, "wall_seconds": time.perf_counter() - started,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
    }
    (args.out / "benchmark.json").write_text(json.dumps(summary, indent=2))
    (args.out / "benchmark.md").write_text(markdown_table(records, profile))
    print(f"wrote {args.out / 'benchmark.json'} and {args.out / 'benchmark.md'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
