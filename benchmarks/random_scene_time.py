"""How long one drawn scene takes to generate at the random sets' size, alone on the machine: the
figure the scene-distribution issue limits (median at most 180 s on the 2-core machine).

    python benchmarks/random_scene_time.py 1003 1004 1005 1006 1007 [--work DIR] [--threads 2]
        [--csv benchmarks/results/random_sets/scene_time.csv]

Each seed runs `generate-scene --random SEED --threads T` in a process of its own, one after the
other, into WORK/random_SEED; nothing else should run meanwhile (the load average before and after
each scene is recorded beside it). A seed whose dataset and record are already in WORK is read,
not generated again, so the command resumes. The CSV has one row per seed: wall seconds, the
worker's render seconds per frame of each pass (times its frames: the pass's share of the scene),
bake and calibration seconds, the loads, the CPU, the scene's RGB optical depth and whether it has
fire.
Prints the median against the limit.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from contracts.atomic import write_rows_csv, write_text  # noqa: E402
from contracts.dataset_format import PASS_FILES, file_path, transforms_name  # noqa: E402
from contracts.float_setup import cpu_facts  # noqa: E402

LIMIT_S = 180.0
RECORD = "time.json"


def cpu_line() -> str:
    """The CPU a time was measured on, and its widest vector unit (Cycles runs faster with AVX-512)."""
    model, flags = cpu_facts()
    return f"{model}, {'AVX-512' if 'avx512f' in flags else 'AVX2' if 'avx2' in flags else 'no AVX2'}"


def generate_one(seed: int, work: Path, threads: int) -> dict[str, Any]:
    """Generate seed's scene into work/random_SEED (unless its record is there) and return the record."""
    out = work / f"random_{seed}"
    record = out / RECORD
    if record.exists():
        return json.loads(record.read_text())
    load_before = os.getloadavg()[0]
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "generator.cli", "--random", str(seed), "--out", str(out),
                    "--threads", str(threads), "--quiet", "--force"], check=True, cwd=ROOT)
    rec = {"seed": seed, "wall_s": round(time.perf_counter() - started, 1), "threads": threads,
           "load_before": round(load_before, 2), "load_after": round(os.getloadavg()[0], 2), "cpu": cpu_line()}
    write_text(record, json.dumps(rec, indent=2))
    return rec


def row(rec: dict[str, Any], work: Path) -> dict[str, Any]:
    """The record with what the dataset says about where the time went."""
    dataset = work / f"random_{rec['seed']}"
    meta = json.loads((dataset / "dataset.json").read_text())
    stems = {m: [f["file_stem"] for f in json.loads((dataset / transforms_name(m)).read_text())["frames"]]
             for m in ("rgb", "thermal")}
    timings = meta["timings_s"]
    out = {**rec, "cpu": rec.get("cpu", "not recorded"), "bake_s": round(timings["bake"], 1),
           "calibration_s": round(timings.get("calibration", 0.0), 1)}
    for key, per_frame in timings["render"].items():
        # The frames the pass holds (a test-view pass: the test views; before that rule, every frame).
        modality, name = key.split(".")
        pf = PASS_FILES[(modality, name)][0]
        rendered = sum(file_path(dataset, pf, s).is_file() for s in stems[modality])
        out[f"{key}_s"] = round(per_frame * rendered, 1)
    out["rgb_optical_depth"] = round(meta["smoke"]["optical_depth"]["achieved"], 3)
    out["fire"] = bool(meta["smoke"]["fire"])
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("seeds", type=int, nargs="+")
    parser.add_argument("--work", type=Path, default=ROOT / "runs" / "random_scene_time")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--csv", type=Path, default=ROOT / "benchmarks/results/random_sets/scene_time.csv")
    args = parser.parse_args(argv)
    rows = []
    for seed in args.seeds:
        rows.append(row(generate_one(seed, args.work, args.threads), args.work))
        print(", ".join(f"{k} {v}" for k, v in rows[-1].items()), flush=True)
    write_rows_csv(args.csv, rows)
    median = statistics.median(r["wall_s"] for r in rows)
    print(f"median {median:.0f} s over {len(rows)} scenes, {median / LIMIT_S:.2f} of the {LIMIT_S:.0f} s limit; "
          f"loads {min(r['load_before'] for r in rows):.1f}-{max(r['load_after'] for r in rows):.1f}")


if __name__ == "__main__":
    main()
