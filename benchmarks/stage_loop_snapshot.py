"""Cost of the NaN guard's last-good snapshot in the shared stage loop.

`smokeseer.train.loop.run_stage` copies the stage state (parameters and Adam moments) before
every optimiser step so the NaN checkpoint can hold the last good state. This measures a
Stage 2 iteration with and without that copy, alternating the two in one process (best of
``--repeats``), on a generated dataset at the quick profile, and the copy alone at the paper
profile's largest state (1M Gaussians, SH degree 3).

    python benchmarks/stage_loop_snapshot.py DATASET [--iterations 40] [--repeats 3]
Writes benchmarks/results/stage_loop_snapshot.csv.
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from smokeseer.api import prepare, _sample  # noqa: E402
from smokeseer.train import loop as trainloop  # noqa: E402
from smokeseer.train.loop import StageSchedule, run_stage  # noqa: E402
from smokeseer.train.stage2 import Stage2Problem  # noqa: E402
from smokeseer.train.util import RunContext, RunLog  # noqa: E402


def stage2_seconds(dataset: Path, out: Path, iterations: int, snapshot: bool) -> tuple[float, int]:
    prep = prepare(dataset, overrides={"progress": False, "stage2.iterations": iterations,
                                       "checkpoint_every": 0, "log_every": iterations})
    cfg, b = prep.cfg, prep.report.bounds
    out.mkdir(parents=True, exist_ok=True)
    for f in out.glob("checkpoints/*.pt"):
        f.unlink()
    ctx = RunContext(cfg, out, RunLog(out / "log.csv"), torch.as_tensor(b.center, dtype=torch.float32), b.extent)
    geo = prep.scene.thermal or prep.scene.rgb
    import numpy as np

    init = _sample(geo, cfg.stage2.init_points, b, np.random.default_rng(0), print, "stage 2 start")
    problem = Stage2Problem(ctx, geo, init, False, None)
    real = trainloop.detached_copy
    trainloop.detached_copy = real if snapshot else (lambda obj: obj)
    try:
        start = time.perf_counter()
        run_stage(ctx, problem, StageSchedule(iterations, iterations, 0, 0, "bench"))
        return (time.perf_counter() - start) / iterations, problem.g.n
    finally:
        trainloop.detached_copy = real


def paper_copy_seconds(n: int = 1_000_000, repeats: int = 3) -> float:
    state = {"gaussians": {"means": torch.randn(n, 3), "quats": torch.randn(n, 4), "log_scales": torch.randn(n, 3),
                           "opacity": torch.randn(n), "thermal": torch.randn(n, 1), "sh_dc": torch.randn(n, 1, 3),
                           "sh_rest": torch.randn(n, 15, 3)}}
    state["moments"] = {k: (torch.randn_like(v), torch.randn_like(v)) for k, v in state["gaussians"].items()}
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        trainloop.detached_copy(state)
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, help="a dataset written by generate-scene")
    ap.add_argument("--iterations", type=int, default=40, help="Stage 2 iterations per measurement")
    ap.add_argument("--repeats", type=int, default=3, help="alternating repeats; the best of each side is kept")
    ap.add_argument("--out", type=Path, default=Path("runs/stage_loop_snapshot"), help="scratch run folder (git-ignored runs/)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    best = {True: float("inf"), False: float("inf")}
    n = 0
    for _ in range(args.repeats):
        for snap in (False, True):
            sec, n = stage2_seconds(args.dataset, args.out, args.iterations, snap)
            best[snap] = min(best[snap], sec)
    copy_paper = paper_copy_seconds()
    load = os.getloadavg()[0]
    rows = [{"case": "quick stage 2 iteration, no snapshot", "seconds": best[False], "gaussians": n},
            {"case": "quick stage 2 iteration, with snapshot", "seconds": best[True], "gaussians": n},
            {"case": "snapshot alone, paper-size state (1M Gaussians, SH 3, Adam)", "seconds": copy_paper,
             "gaussians": 1_000_000}]
    out = ROOT / "benchmarks" / "results" / "stage_loop_snapshot.csv"
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="") as fh:
        w = csv.DictWriter(fh, ["case", "seconds", "gaussians", "load_avg_1min", "threads"])
        w.writeheader()
        for r in rows:
            w.writerow({**r, "load_avg_1min": f"{load:.2f}", "threads": 1})
    for r in rows:
        print(f"{r['case']}: {r['seconds'] * 1000:.2f} ms ({r['gaussians']} Gaussians)")
    print(f"with/without snapshot: {best[True] / best[False]:.3f}x; load average {load:.2f}; 1 torch thread")


if __name__ == "__main__":
    main()
