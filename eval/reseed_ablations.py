"""Which of Table 2's ablations get seeds 1-2 beside seed 0.

Why: at one seed, a row whose mean sits close to Full's cannot be told apart from it (Full's own
seed std on the ten-scene mean is 0.1-0.2 dB), so its sign needs the other seeds; a row well
below Full is settled at seed 0. The rule: an ablation whose seed-0 runs have finished on every
scene asked for (where Full's run stands for it, eval/twins.py, with Full's score) and whose mean
over them is at least Full's seed-0 mean over the same scenes minus RESEED_MARGIN_DB. A row above
Full counts too: it is the one that would break "every ablation ≤ Full + 0.1 dB".

    python -m eval.reseed_ablations TABLES --scenes a,b,c [--profile standard] [--digest PREFIX]

prints one ablation per line (the queue and benchmarks/standard_tables.sh read it).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from contracts.results_format import ResultsFormatError
from contracts.source import code_digest
from eval.finished_runs import finished_runs
from eval.harness import TRAINER_ENTRY
from eval.settings import default_ablations
from eval.twins import run_twin_reason

RESEED_MARGIN_DB = 0.3


def seed0_means(tables: Path, scenes: list[str], variants: list[str], digest: str) -> dict[str, float]:
    """{variant: mean test PSNR over ``scenes`` at seed 0} for each variant finished on all of them.
    On a scene where Full's seed-0 run stands for the ablation's (eval/twins.py: the harness never
    trains that run, so it has no folder), the ablation scores Full's PSNR there."""
    try:
        _, runs = finished_runs(tables, variants, digest)
    except ValueError:
        return {}
    psnr: dict[str, dict[str, float]] = {}
    full_runs: dict[str, Path] = {}
    for run_dir, rec in runs:
        if rec["seed"] == 0 and rec["scene"] in scenes:
            psnr.setdefault(rec["variant"], {})[rec["scene"]] = float(rec["metrics"]["psnr"])
            if rec["variant"] == "full":
                full_runs[rec["scene"]] = run_dir
    for variant in variants:
        for scene, full_dir in full_runs.items():
            if scene not in psnr.get(variant, {}) and run_twin_reason(variant, full_dir):
                psnr.setdefault(variant, {})[scene] = psnr["full"][scene]
    return {v: sum(by_scene.values()) / len(scenes) for v, by_scene in psnr.items() if set(by_scene) >= set(scenes)}


def ablations_to_reseed(tables: Path, scenes: list[str], ablations: list[str], digest: str) -> list[str]:
    """The ablations, in the order given, that the rule in this module's docstring picks."""
    means = seed0_means(tables, scenes, ["full", *ablations], digest)
    if "full" not in means:
        return []
    return [a for a in ablations if a in means and means[a] >= means["full"] - RESEED_MARGIN_DB]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m eval.reseed_ablations", description=__doc__.split("\n\n")[0])
    ap.add_argument("tables", type=Path, help="a regenerate-tables --out folder")
    ap.add_argument("--scenes", required=True, help="comma-separated scenes the means are taken over")
    ap.add_argument("--profile", default="standard", help="the profile whose Table 2 rows are checked")
    ap.add_argument("--digest", default=None, help="trainer code digest prefix (default: today's trainer)")
    args = ap.parse_args(argv)
    scenes = [s for s in args.scenes.split(",") if s]
    if not scenes:
        print("python -m eval.reseed_ablations: error: --scenes is empty", file=sys.stderr)
        return 2
    digest = args.digest or code_digest(TRAINER_ENTRY)
    try:
        reseed = ablations_to_reseed(args.tables, scenes, default_ablations(args.profile, {}), digest)
    except ResultsFormatError as exc:  # a Full run whose metrics.json breaks the contract: the rule cannot decide
        print(f"python -m eval.reseed_ablations: error: {exc}", file=sys.stderr)
        return 1
    for a in reseed:
        print(a)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
