"""Full against RGB-only on a drawn set, one row per scene, with the set's own smoke thickness beside
each score: what the rules issue's must-holds read on `random-test`, and what a rule is chosen on
(validation views) on `random-dev`.

    python benchmarks/random_set_scores.py --tables data/tables_random_test --datasets data/random_test \
        --out benchmarks/results/random_test/per_scene.csv [--split test] [--seed 0] [--digest PREFIX]

The runs are the finished Full and RGB-only runs of one trainer version in the tables folder
(`eval.finished_runs`; `--digest` names it, else the one with the most runs), trained by
`regenerate-tables --scenes random_... --dataset random_...=DATASETS/random_... --methods full,rgb-only`.
`--split val` reads each run's validation PSNRs (the views a rule is chosen on) instead of the test
views. `rgb_optical_depth` is the set's axis: the mean RGB optical depth of the smoke over the views
(dataset.json `smoke.optical_depth.achieved`). Prints the counts the must-holds read: Full within
0.3 dB of RGB-only or better, Full's lead on the scenes at optical depth 1 or more, Full over the
smoky input.

`--candidates start-thermal,...` reads the rule candidates run beside Full (`regenerate-tables
--candidates`) too: each gets a column, and the same counts with it in Full's place, plus its
paired difference from Full (mean, std over scenes, scenes ahead). That is what a rule is chosen on,
with `--split val` on random-dev; `--summary CSV` writes those counts, one row per rule. With
candidates a scene needs Full and every candidate, not RGB-only: the counts against RGB-only read
the scenes where it was trained, and say how many. A candidate that would train exactly like Full
on a scene has no run folder there (the harness took Full's run, `eval/twins.py`): it reads Full's,
and the row's `same_as_full` names it.

Runs of one scene need not come from one machine: the harness takes a finished run of the same
settings wherever it was trained. `machines` names each run's CPU and torch capability (harness.json
`float_setup`), and the printout says how many scenes mix float setups, since a paired difference
between machines carries their rounding too (up to a dB on one scene between an AVX-512 and an AVX2
machine).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from contracts.atomic import write_rows_csv  # noqa: E402
from contracts.float_setup import machine_of  # noqa: E402
from eval.finished_runs import finished_runs  # noqa: E402
from eval.twins import stood_for  # noqa: E402

DENSE = 1.0
"""The optical depth from which a scene counts as dense smoke (the must-hold's split)."""


def _psnrs(run: Path, rec: dict[str, Any], split: str) -> tuple[float, float]:
    """(the method's PSNR, the smoky input's) on ``split`` views."""
    if split == "test":
        return float(rec["metrics"]["psnr"]), float(rec["metrics"]["psnr_input"])
    validation = json.loads((run / "metrics.json").read_text()).get("validation") or {}
    if validation.get("psnr") is None:
        raise ValueError(f"{run / 'metrics.json'}: validation: no validation views (a profile with validation_every)")
    return float(validation["psnr"]), float(validation["psnr_input"])


def column(variant: str) -> str:
    return variant.replace("-", "_") + "_psnr"


def score_rows(tables: Path, datasets: Path, split: str, seed: int, digest: str | None,
               candidates: tuple[str, ...] = ()) -> tuple[str, list[dict[str, Any]]]:
    """(trainer digest, one row per scene where both methods, and every candidate, finished at ``seed``)."""
    chosen, runs = finished_runs(tables, ["full", "rgb-only", *candidates], digest)
    by_scene: dict[str, dict[str, tuple[Path, dict[str, Any]]]] = {}
    for run, rec in runs:
        if rec["seed"] == seed:
            by_scene.setdefault(rec["scene"], {})[rec["variant"]] = (run, rec)
    required = {"full", *candidates} if candidates else {"full", "rgb-only"}
    rows = []
    for scene in sorted(by_scene):
        found = by_scene[scene]
        twins = stood_for(candidates, found)
        found.update({c: found["full"] for c in twins})  # the harness took Full's run for it (eval/twins.py)
        if not required <= set(found):
            continue
        meta = json.loads((datasets / scene / "dataset.json").read_text())
        depth = (meta.get("smoke", {}).get("optical_depth") or {}).get("achieved")
        full, full_input = _psnrs(*by_scene[scene]["full"], split)
        rgb = _psnrs(*by_scene[scene]["rgb-only"], split)[0] if "rgb-only" in by_scene[scene] else None
        setups = {rec.get("float_setup") or "" for _, rec in by_scene[scene].values()}
        rows.append({"scene": scene, "rgb_optical_depth": depth, "input_psnr": round(full_input, 4),
                     "full_psnr": round(full, 4), "rgb_only_psnr": None if rgb is None else round(rgb, 4),
                     "full_minus_rgb_only": None if rgb is None else round(full - rgb, 4),
                     "full_minus_input": round(full - full_input, 4),
                     **{column(c): round(_psnrs(*by_scene[scene][c], split)[0], 4) for c in candidates},
                     "float_setups": len(setups), "same_as_full": ",".join(twins),
                     "machines": "; ".join(f"{v}: {machine_of(by_scene[scene][v][1].get('float_setup') or '')}" for v in sorted(by_scene[scene]))})
    return chosen, rows


def counts(rows: list[dict[str, Any]], variant: str = "full") -> dict[str, Any]:
    """What the must-holds read, for ``variant`` (Full, or a candidate in its place): scenes within
    0.3 dB of RGB-only or better, its mean lead on dense scenes (optical depth >= 1), scenes where it
    beats the input; and its paired difference from Full."""
    score = np.array([r[column(variant)] for r in rows])
    paired = np.array([r["rgb_only_psnr"] is not None for r in rows])
    lead = score[paired] - np.array([r["rgb_only_psnr"] for r in rows if r["rgb_only_psnr"] is not None])
    over_full = score - np.array([r["full_psnr"] for r in rows])
    dense = np.array([r["rgb_optical_depth"] is not None and r["rgb_optical_depth"] >= DENSE
                      for r in rows], dtype=bool)[paired]
    return {"rule": variant, "scenes": len(rows), "mean_psnr": float(score.mean()),
            "rgb_only_scenes": int(paired.sum()), "within_0.3": int((lead >= -0.3).sum()) if paired.any() else None,
            "dense_scenes": int(dense.sum()), "dense_mean_lead": float(lead[dense].mean()) if dense.any() else None,
            "beats_input": int(sum(score > np.array([r["input_psnr"] for r in rows]))),
            "mean_lead": float(lead.mean()) if paired.any() else None, "minus_full_mean": float(over_full.mean()),
            "minus_full_std": float(over_full.std(ddof=1)) if len(rows) > 1 else 0.0,
            "ahead_of_full": int((over_full > 0).sum())}


def describe(c: dict[str, Any]) -> str:
    dense = "n/a" if c["dense_mean_lead"] is None else f"{c['dense_mean_lead']:+.2f} dB"
    of = "" if c["rgb_only_scenes"] == c["scenes"] else f" (RGB-only trained on {c['rgb_only_scenes']} of them)"
    versus = ("RGB-only not trained; " if c["rgb_only_scenes"] == 0 else
              f"within 0.3 dB of RGB-only or better on {c['within_0.3']}{of}; - RGB-only {c['mean_lead']:+.2f} dB "
              f"on the mean, {dense} on the {c['dense_scenes']} scenes at optical depth >= {DENSE:g}; ")
    line = f"{c['rule']}: mean {c['mean_psnr']:.2f} dB; {versus}over the smoky input on {c['beats_input']}"
    if c["rule"] != "full":
        line += (f"; - Full {c['minus_full_mean']:+.2f} ± {c['minus_full_std']:.2f} dB, ahead on "
                 f"{c['ahead_of_full']} of {c['scenes']}")
    return line


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python benchmarks/random_set_scores.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tables", type=Path, required=True, help="the regenerate-tables folder that trained the set")
    p.add_argument("--datasets", type=Path, required=True, help="the set's folder (generate-benchmark --random)")
    p.add_argument("--out", type=Path, required=True, help="the per-scene CSV")
    p.add_argument("--split", choices=("test", "val"), default="test")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--digest", help="the trainer version whose runs to read (a digest prefix)")
    p.add_argument("--candidates", default="", help="comma list of rule candidates run beside Full")
    p.add_argument("--summary", type=Path, help="also write the counts, one row per rule, to this CSV")
    args = p.parse_args(argv)
    candidates = tuple(c for c in args.candidates.split(",") if c)
    try:
        digest, rows = score_rows(args.tables, args.datasets, args.split, args.seed, args.digest, candidates)
    except (ValueError, FileNotFoundError) as exc:
        print(f"random_set_scores: error: {exc}", file=sys.stderr)
        return 2
    if not rows:
        print(f"random_set_scores: error: {args.tables}: no scene has finished "
              f"{'Full and every candidate' if candidates else 'Full and RGB-only runs'} at seed {args.seed}",
              file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_rows_csv(args.out, rows)
    summary = [counts(rows, v) for v in ("full", *candidates)]
    mixed = sum(r["float_setups"] > 1 for r in rows)
    print(f"trainer {digest[:8]}, {args.split} views, seed {args.seed}: {len(rows)} scenes"
          f"{f', {mixed} of them with runs from more than one float setup (column machines)' if mixed else ''}; "
          f"wrote {args.out}")
    for c in summary:
        print("  " + describe(c))
    if args.summary:
        write_rows_csv(args.summary, summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
