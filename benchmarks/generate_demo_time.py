"""Demo generation time: this checkout against an earlier commit, alternated in one process.

    python benchmarks/generate_demo_time.py --baseline c300de9 [--repeats 3]

Runs `generate-scene --preset demo` end to end (fresh output and staging folders each time),
alternating the baseline commit (exported with `git archive` to a temporary folder and put
first on PYTHONPATH) and the working tree, and keeps the best wall time of each side. Prints
the ratio and the load average before and after. Writes benchmarks/results/generate_demo_time.csv.
"""
from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"


def export_commit(rev: str, dest: Path) -> None:
    archive = subprocess.run(["git", "archive", rev], cwd=REPO, capture_output=True, check=True).stdout
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(dest, filter="data")


def timed_demo(source_root: Path, out: Path) -> float:
    env = {**os.environ, "PYTHONPATH": str(source_root)}
    t0 = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "generator.cli", "--preset", "demo", "--out", str(out), "--quiet"],
                            cwd=source_root, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if result.returncode != 0:
        raise SystemExit(f"generate-scene failed in {source_root}: {result.stderr.strip()[-500:]}")
    return seconds


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", required=True, help="git revision to compare against")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each side (best kept)")
    args = parser.parse_args()
    times: dict[str, list[float]] = {"baseline": [], "current": []}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        export_commit(args.baseline, tmp / "baseline")
        print(f"load average before: {loadavg()}")
        for i in range(args.repeats):
            for side, root in (("baseline", tmp / "baseline"), ("current", REPO)):
                seconds = timed_demo(root, tmp / f"{side}{i}" / "demo")
                times[side].append(seconds)
                print(f"  {side:<8} run {i}: {seconds:.1f} s", flush=True)
        print(f"load average after: {loadavg()}")
    best = {side: min(v) for side, v in times.items()}
    ratio = best["current"] / best["baseline"]
    print(f"best: baseline {best['baseline']:.1f} s, current {best['current']:.1f} s, ratio x{ratio:.2f}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    with (RESULTS / "generate_demo_time.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["side", "revision", "runs_s", "best_s", "ratio_to_baseline"])
        writer.writerow(["baseline", args.baseline, " ".join(f"{t:.2f}" for t in times["baseline"]),
                         f"{best['baseline']:.2f}", "1.00"])
        writer.writerow(["current", "working tree", " ".join(f"{t:.2f}" for t in times["current"]),
                         f"{best['current']:.2f}", f"{ratio:.2f}"])


if __name__ == "__main__":
    main()
