"""Validation PSNR against Stage-3 time for the ways the smoke can move (``deform.*``): the
paper's network at the standard width, a narrower one, per-Gaussian Fourier trajectories, and
the plane field at any settings.

    python benchmarks/deformation_tradeoff.py [--table deformation] [--profile DIR] [--out DIR]

Reads the candidate table ``benchmarks/results/full_candidates/TABLE_final.csv`` (one finished
standard run per scene, seed and trainer: ``estimated-floor`` for today's standard Full,
``width 64`` for ``--set deform.width=64``, ``fourier`` for ``--set deform.kind=fourier``, or a
trainer named by its settings, ``deform.kind=planes deform.planes_levels=1``: the ``--set``
values of its runs, space-separated, ``stage3.iterations=N`` among them where it ran N) and the
quiet per-iteration cost of each from ``iteration_profile.csv`` (``benchmarks/iteration_profile.py
--set ...``: the thread CPU milliseconds of an unprofiled Stage-3 iteration at that scene's
Gaussian counts, its column named ``full`` plus the same overrides, less the iteration count,
which does not change an iteration's cost). The runs' own wall times are not used: they ran two at a time,
on more than one machine. Writes ``deformation_tradeoff.csv`` (per scene and trainer: seeds,
mean and std of the final validation PSNR, Stage-3 ms per iteration, iterations, and the Stage-3
minutes they make), ``deformation_tradeoff_summary.csv`` (per trainer, over the scenes it shares
with ``estimated-floor``: the mean and the worst difference in validation PSNR, and the mean
Stage-3 time as a share of the network's) and ``deformation_tradeoff.png`` (one panel per scene).
The ten-scene sweep that fills the table: ``benchmarks/deformation_sweep.sh``.
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
"""Each named trainer label of the table: the iteration_profile column of its settings, and its
Stage-3 iterations (``fourier, 6000``: ``--set stage3.iterations=6000`` as well)."""
BASELINE = "estimated-floor"
STANDARD_ITERATIONS = 3000


def profiled(trainer: str) -> tuple[str, int] | None:
    """The iteration_profile column and the Stage-3 iterations of a trainer label: a named one
    (``PROFILED``), or one spelled as its settings (``KEY=VALUE`` words); None for any other."""
    if trainer in PROFILED:
        return PROFILED[trainer]
    words = trainer.split()
    if not words or not all("=" in w and not w.startswith("=") for w in words):
        return None
    settings = dict(w.split("=", 1) for w in words)
    iterations = int(settings.pop("stage3.iterations", STANDARD_ITERATIONS))
    return " ".join(["full", *(f"{k}={v}" for k, v in settings.items())]), iterations


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
                    if (scene, (profiled(t) or ("", 0))[0]) in costs]
        if len(trainers) < 2 or len({costs[(scene, profiled(t)[0])][1] for t in trainers}) > 1:
            print(f"deformation_tradeoff: {scene}: left out (fewer than two trainers profiled by one commit)")
            continue
        for trainer in trainers:
            column, iterations = profiled(trainer)
            cost = costs[(scene, column)][0]
            vals = [float(r["val_psnr"]) for r in final if (r["scene"], r["trainer"]) == (scene, trainer)]
            seeds = sorted(int(r["seed"]) for r in final if (r["scene"], r["trainer"]) == (scene, trainer))
            rows.append({"scene": scene, "trainer": trainer, "seeds": " ".join(map(str, seeds)),
                         "val_psnr_mean": round(statistics.fmean(vals), 3),
                         "val_psnr_std": round(statistics.stdev(vals), 3) if len(vals) > 1 else "",
                         "stage3_ms_per_iteration": round(cost, 1), "stage3_iterations": iterations,
                         "stage3_min": round(cost * iterations / 60e3, 1)})
    return rows


def summary_rows(rows: list[dict]) -> list[dict]:
    """Per trainer other than the baseline, over the scenes both have: the mean and the worst
    (scene) difference in mean validation PSNR, and the mean Stage-3 time over the baseline's."""
    by = {(r["scene"], r["trainer"]): r for r in rows}
    out = []
    for trainer in dict.fromkeys(r["trainer"] for r in rows if r["trainer"] != BASELINE):
        scenes = [s for (s, t) in by if t == trainer and (s, BASELINE) in by]
        if not scenes:
            continue
        deltas = {s: by[(s, trainer)]["val_psnr_mean"] - by[(s, BASELINE)]["val_psnr_mean"] for s in scenes}
        worst = min(deltas, key=deltas.get)
        out.append({"trainer": trainer, "scenes": len(scenes),
                    "mean_val_psnr_minus_baseline": round(statistics.fmean(deltas.values()), 3),
                    "worst_scene": worst, "worst_val_psnr_minus_baseline": round(deltas[worst], 3),
                    "stage3_time_over_baseline": round(statistics.fmean(
                        by[(s, trainer)]["stage3_min"] / by[(s, BASELINE)]["stage3_min"] for s in scenes), 3)})
    return out


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
    summary = summary_rows(rows)
    write_rows_csv(args.out / "deformation_tradeoff.csv", rows)
    if summary:
        write_rows_csv(args.out / "deformation_tradeoff_summary.csv", summary)
    plot(rows, args.out / "deformation_tradeoff.png")
    for r in rows:
        print(f"{r['scene']:>10} {r['trainer']:>22}: {r['val_psnr_mean']:.2f} dB (seeds {r['seeds']}), "
              f"{r['stage3_ms_per_iteration']:.0f} ms/it, {r['stage3_min']:.1f} min")
    for r in summary:
        print(f"{r['trainer']}: {r['scenes']} scenes, {r['mean_val_psnr_minus_baseline']:+.3f} dB mean, worst "
              f"{r['worst_scene']} {r['worst_val_psnr_minus_baseline']:+.3f} dB, Stage 3 × "
              f"{r['stage3_time_over_baseline']:.2f} of {BASELINE}'s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
