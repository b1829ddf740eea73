"""Validation PSNR against Stage-3 time for the ways the smoke can move (``deform.*``): the
paper's network at the standard width, a narrower one, and per-Gaussian Fourier trajectories.

    python benchmarks/deformation_tradeoff.py [--table deformation] [--profile DIR] [--out DIR]

Reads the candidate table ``benchmarks/results/full_candidates/TABLE_final.csv`` (one finished
standard run per scene, seed and trainer: ``estimated-floor`` for today's standard Full,
``width 64`` for ``--set deform.width=64``, ``fourier`` for ``--set deform.kind=fourier``) and the
quiet per-iteration cost of each from ``iteration_profile.csv`` (``benchmarks/iteration_profile.py
--set ...``: the thread CPU milliseconds of an unprofiled Stage-3 iteration at that scene's
Gaussian counts, its column named ``full`` plus the same overrides). The runs' own wall times are not used: they ran two at a time,
on more than one machine. Writes ``deformation_tradeoff.csv`` (per scene and trainer: seeds,
mean and std of the final validation PSNR, Stage-3 ms per iteration, iterations, and the Stage-3
minutes they make) and ``deformation_tradeoff.png`` (one panel per scene).
"""
from __future__ import annotations

import argparse
import csv
import statistics
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.full_candidates import OUT as CANDIDATES, save_panels  # noqa: E402
from contracts.atomic import write_rows_csv  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
PROFILED = {"estimated-floor": ("full", 3000), "width 64": ("full deform.width=64", 3000),
            "fourier": ("full deform.kind=fourier", 3000), "fourier, 6000": ("full deform.kind=fourier", 6000)}
"""Each trainer label of the table: the iteration_profile column of its settings, and its Stage-3
iterations (``fourier, 6000``: ``--set stage3.iterations=6000`` as well)."""


def stage3_costs(path: Path) -> dict[tuple[str, str], tuple[float, str]]:
    """(scene, profile column) -> (unprofiled Stage-3 thread CPU ms per iteration, code commit)."""
    with path.open(newline="") as fh:
        return {(r["scene"], r["mode"]): (float(r["unprofiled_cpu_ms_per_iteration"]), r["commit"])
                for r in csv.DictReader(fh) if r["stage"] == "3" and r["part"] == "total"}


def tradeoff_rows(final: list[dict], costs: dict[tuple[str, str], tuple[float, str]]) -> list[dict]:
    """Scenes where at least two trainers were profiled by one commit (costs of different code
    do not compare); the committed RGB-only beside each table is never profiled."""
    rows = []
    for scene in dict.fromkeys(r["scene"] for r in final):
        trainers = [t for t in dict.fromkeys(r["trainer"] for r in final if r["scene"] == scene)
                    if (scene, PROFILED.get(t, ("", 0))[0]) in costs]
        if len(trainers) < 2 or len({costs[(scene, PROFILED[t][0])][1] for t in trainers}) > 1:
            print(f"deformation_tradeoff: {scene}: left out (fewer than two trainers profiled by one commit)")
            continue
        for trainer in trainers:
            column, iterations = PROFILED[trainer]
            cost = costs[(scene, column)][0]
            vals = [float(r["val_psnr"]) for r in final if (r["scene"], r["trainer"]) == (scene, trainer)]
            seeds = sorted(int(r["seed"]) for r in final if (r["scene"], r["trainer"]) == (scene, trainer))
            rows.append({"scene": scene, "trainer": trainer, "seeds": " ".join(map(str, seeds)),
                         "val_psnr_mean": round(statistics.fmean(vals), 3),
                         "val_psnr_std": round(statistics.stdev(vals), 3) if len(vals) > 1 else "",
                         "stage3_ms_per_iteration": round(cost, 1), "stage3_iterations": iterations,
                         "stage3_min": round(cost * iterations / 60e3, 1)})
    return rows


def plot(rows: list[dict], path: Path) -> None:
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    trainers = list(dict.fromkeys(r["trainer"] for r in rows))

    def draw(ax: Any, i: int) -> None:
        for k, trainer in enumerate(trainers):
            for r in (r for r in rows if (r["scene"], r["trainer"]) == (scenes[i], trainer)):
                ax.errorbar([r["stage3_min"]], [r["val_psnr_mean"]], yerr=[r["val_psnr_std"] or 0.0], fmt="o",
                            capsize=3, color=f"C{k % 10}", label=f"{trainer} (seeds {r['seeds']})")
    save_panels(path, scenes, draw, "Stage 3, one thread, quiet (min)", "validation PSNR (dB), mean ± std over seeds")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", default="deformation", help="full_candidates table NAME")
    p.add_argument("--profile", type=Path, default=RESULTS, help="folder of iteration_profile.csv")
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)
    final_path = CANDIDATES / f"{args.table}_final.csv"
    try:
        with final_path.open(newline="") as fh:
            final = list(csv.DictReader(fh))
        rows = tradeoff_rows(final, stage3_costs(args.profile / "iteration_profile.csv"))
    except (OSError, KeyError, ValueError) as exc:
        print(f"deformation_tradeoff: error: {exc}", file=sys.stderr)
        return 2
    if not rows:
        print(f"deformation_tradeoff: error: no trainer of {final_path} has a profiled Stage-3 cost", file=sys.stderr)
        return 2
    write_rows_csv(args.out / "deformation_tradeoff.csv", rows)
    plot(rows, args.out / "deformation_tradeoff.png")
    for r in rows:
        print(f"{r['scene']:>10} {r['trainer']:>22}: {r['val_psnr_mean']:.2f} dB (seeds {r['seeds']}), "
              f"{r['stage3_ms_per_iteration']:.0f} ms/it, {r['stage3_min']:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
