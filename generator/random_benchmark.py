"""`generate-benchmark --random N --seed-base S`: a set of N drawn scenes, seeds S to S+N-1.

Each scene goes to OUT/random_SEED/ through `generator.api.generate_random`, on a Dask
scheduler (a LocalCluster of W single-threaded workers by default, as `regenerate-tables` runs
its trainings), each scene rendering with the machine's cores / W threads. A scene whose dataset
is already there and was made from the same drawn spec is skipped, and an interrupted scene
resumes in the generator's staging folder, so rerunning the command resumes the set. The run
writes OUT/benchmark.json and OUT/benchmark.md with each scene's generation time and axes.
"""
from __future__ import annotations

import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

from contracts.atomic import write_json, write_text
from contracts.errors import DatasetError
from contracts.executors import drain, open_executor
from contracts.provenance import provenance
from generator.api import generate_random, random_spec
from generator.errors import GeneratorError
from generator.pipeline import made_from
from generator.profiles import RANDOM_PROFILE
from generator.spec import SceneSpec


def scene_name(seed: int) -> str:
    return f"random_{seed}"


def _load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def random_scene_task(seed: int, pins: list[str], out_root: str, threads: int, force: bool) -> dict[str, Any]:
    """Generate (or reuse) the scene of `seed`; its record. Runs in a scheduler's worker."""
    spec, _ = random_spec(seed, pins)
    out = Path(out_root) / scene_name(seed)
    if not force and made_from(out, spec):
        return scene_record(seed, spec, out, "reused", None, None)
    load_before = _load()
    started = time.perf_counter()
    generate_random(seed, out, pins=pins, force=True, show_progress=False, threads=threads)
    return scene_record(seed, spec, out, "generated", time.perf_counter() - started, load_before)


def scene_record(seed: int, spec: SceneSpec, out: Path, status: str, seconds: float | None,
                 load_before: list[float] | None) -> dict[str, Any]:
    """A reused scene gets no load averages: today's load says nothing about its generation time
    (``keep_generation_loads`` carries them over from the call that generated it)."""
    meta = json.loads((out / "dataset.json").read_text())
    depth = meta["smoke"].get("optical_depth") or {}
    wind = spec.sim.wind
    return {
        "scene": scene_name(seed), "seed": seed, "status": status,
        "seconds": seconds if seconds is not None else meta["timings_s"]["total"],
        "timings_s": meta["timings_s"], "load_average_before": load_before,
        "load_average_after": None if load_before is None else _load(),
        "objects": len(spec.objects) - 1, "sources": len(spec.sources), "fire": spec.has_fire,
        "particles": spec.smoke.particles, "trajectory": spec.rig.trajectory.kind,
        "wind": round(float(sum(v * v for v in wind)) ** 0.5, 3),
        "thermal_size": [spec.rig.thermal.width, spec.rig.thermal.height],
        "optical_depth_target": depth.get("target"), "optical_depth_achieved": depth.get("achieved"),
        "calibration_scale": depth.get("calibration_scale"), "stats": meta.get("stats", {}),
        "code_sha256": meta.get("code_sha256"),
    }


def earlier_records(out: Path) -> dict[str, dict[str, Any]]:
    """The scene records of OUT's last ``benchmark.json`` (none if it is missing or unreadable)."""
    try:
        return {r["scene"]: r for r in json.loads((out / "benchmark.json").read_text())["scenes"]}
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def keep_generation_loads(record: dict[str, Any], earlier: dict[str, Any] | None) -> dict[str, Any]:
    """A reused scene's record with the load averages measured when it was generated, from an earlier
    call's record of the same dataset (same generator code and optical depth) that measured them."""
    same = (earlier is not None and earlier.get("code_sha256") == record["code_sha256"]
            and earlier.get("optical_depth_achieved") == record["optical_depth_achieved"])
    if record["status"] != "reused" or not same or earlier.get("load_average_before") is None:
        return record
    if earlier.get("status") == "reused" and not earlier.get("load_from_earlier_call"):
        return record  # written before reused scenes kept their loads: that load was the reusing call's
    return {**record, "load_average_before": earlier["load_average_before"],
            "load_average_after": earlier.get("load_average_after"), "load_from_earlier_call": True}


def _first(values: list[float] | None) -> float | None:
    return values[0] if values else None


def _fmt(value: Any, spec: str) -> str:
    return format(value, spec) if isinstance(value, (int, float)) else "n/a"


def markdown_table(records: list[dict[str, Any]], summary: dict[str, Any]) -> str:
    head = ("| scene | status | time (s) | load before | objects | sources | fire | particles | path | wind "
            "| thermal | optical depth target | achieved |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    rows = [f"| {r['scene']} | {r['status']} | {r['seconds']:.0f} "
            f"| {_fmt(_first(r['load_average_before']), '.1f')} | {r['objects']} | {r['sources']} "
            f"| {'yes' if r['fire'] else 'no'} | {r['particles']} "
            f"| {r['trajectory']} | {r['wind']:.1f} | {r['thermal_size'][0]}x{r['thermal_size'][1]} "
            f"| {_fmt(r['optical_depth_target'], '.3f')} | {_fmt(r['optical_depth_achieved'], '.3f')} |"
            for r in records]
    generated = [r["seconds"] for r in records if r["status"] == "generated"]
    timing = (f"Generated {len(generated)} scene(s): median {statistics.median(generated):.0f} s per scene "
              f"({summary['workers']} worker(s), {summary['threads_per_worker']} thread(s) each)."
              if generated else "No scene was generated in this run (all reused).")
    timing += (" A reused scene's time and load are those of the call that generated it; its load is n/a "
               "where no record of that call survives.")
    return (f"Random set: seeds {summary['seed_base']}-{summary['seed_base'] + summary['count'] - 1}, "
            f"pins {', '.join(summary['pins']) or 'none'}, size `{RANDOM_PROFILE.name}` "
            f"({RANDOM_PROFILE.description}).\n\n" + head + "\n".join(rows)
            + f"\n\n{timing} Failed: {', '.join(summary['failed']) or 'none'}. "
              f"Wall time {summary['wall_seconds']:.0f} s.\n")


def run_random_set(count: int, seed_base: int, pins: list[str], out: Path, workers: int, scheduler: str,
                   force: bool, quiet: bool = False) -> int:
    """Generate the set; prints a line per scene and writes benchmark.json and benchmark.md."""
    seeds = list(range(seed_base, seed_base + count))
    try:  # bad pins or seeds are one line before any scene starts
        for seed in (seeds[0], seeds[-1]):
            random_spec(seed, pins)
    except GeneratorError as exc:
        print(f"generate-benchmark: error: {exc}", file=sys.stderr)
        return 2
    threads = max(1, (os.cpu_count() or 1) // workers)
    out.mkdir(parents=True, exist_ok=True)
    records: dict[int, dict[str, Any]] = {}
    failed: list[str] = []
    started = time.perf_counter()

    def done(seed: int):
        def ok(record: dict[str, Any]) -> None:
            records[seed] = record
            tqdm.write(f"{record['scene']:<14} {record['status']:<9} {record['seconds']:7.1f} s  optical depth "
                       f"{_fmt(record['optical_depth_achieved'], '.3f')} (target "
                       f"{_fmt(record['optical_depth_target'], '.3f')})")

        def fail(exc: BaseException) -> None:
            failed.append(scene_name(seed))
            reason = str(exc) if isinstance(exc, (GeneratorError, DatasetError)) else f"{type(exc).__name__}: {exc}"
            tqdm.write(f"{scene_name(seed):<14} FAILED: {reason}")

        return ok, fail

    jobs = [(random_scene_task, (seed, pins, str(out.resolve()), threads, force), *done(seed)) for seed in seeds]
    with (open_executor(workers, scheduler) as ex,
          tqdm(total=len(jobs), desc="scenes", unit="scene", disable=quiet) as bar):
        drain(ex, jobs, bar)
        where = ex.description
    earlier = earlier_records(out)
    ordered = [keep_generation_loads(records[s], earlier.get(scene_name(s))) for s in seeds if s in records]
    summary = {"kind": "random", "seed_base": seed_base, "count": count, "pins": pins, "size": RANDOM_PROFILE.kwargs(),
               "workers": workers, "threads_per_worker": threads, "scheduler": where, "scenes": ordered,
               "failed": sorted(failed), "wall_seconds": time.perf_counter() - started,
               "provenance": provenance("generator.random_benchmark", threads)}
    write_json(out / "benchmark.json", summary)
    write_text(out / "benchmark.md", markdown_table(ordered, summary))
    print(f"wrote {out / 'benchmark.json'} and {out / 'benchmark.md'}")
    return 1 if failed else 0
