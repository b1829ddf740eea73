"""Does a shorter training profile rank the rules as the standard profile does? Rules are chosen on
40 drawn scenes; at the standard profile that is days of this machine, so the choice may run at a
shorter one (a proxy) only where the proxy is shown to rank the candidates as the standard profile
does on the ten standard scenes (rules issue, item 4).

    python benchmarks/proxy_ranking.py --standard data/tables_rules_standard --proxy data/tables_rules_proxy \
        --variants full,start-thermal,start-clear-views [--split val] [--seed 0] \
        [--digest PREFIX] [--out benchmarks/results/rules/proxy_ranking.csv]

Both folders are `regenerate-tables` outputs over the same scenes with the same variants (methods
and `--candidates`), one at each profile. For every scene where every variant finished at both,
each candidate's difference from the first variant (the reference, Full) is compared: the
Spearman rank correlation of those differences over all scenes and candidates (what decides a
choice: which candidate gains where), the share of pairs of (scene, candidate) the two profiles
order alike, and per scene whether both profiles name the same best variant. The ranking of the
variants by their mean over the scenes is printed for each profile. Validation views by default:
that is what a rule is chosen on.
"""
from __future__ import annotations

import argparse
import json
import sys
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import spearmanr

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from contracts.atomic import write_rows_csv  # noqa: E402
from eval.finished_runs import finished_runs  # noqa: E402


def scores(tables: Path, variants: list[str], split: str, seed: int,
           digest: str | None = None) -> tuple[str, dict[str, dict[str, float]]]:
    """(trainer digest, {scene: {variant: PSNR on ``split`` views}}) of the finished runs at ``seed`` of
    one trainer (``digest``, a prefix; else the one with the most runs)."""
    digest, runs = finished_runs(tables, variants, digest)
    out: dict[str, dict[str, float]] = {}
    for run, rec in runs:
        if rec["seed"] != seed:
            continue
        if split == "test":
            value = rec["metrics"]["psnr"]
        else:
            value = (json.loads((run / "metrics.json").read_text()).get("validation") or {}).get("psnr")
            if value is None:
                raise ValueError(f"{run / 'metrics.json'}: validation: no validation views")
        out.setdefault(rec["scene"], {})[rec["variant"]] = float(value)
    return digest, out


def compare(standard: dict[str, dict[str, float]], proxy: dict[str, dict[str, float]],
            variants: list[str]) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """One row per (scene, variant) finished under both profiles, and the agreement summary."""
    reference, candidates = variants[0], variants[1:]
    scenes = sorted(s for s in standard if s in proxy
                    and all(v in standard[s] and v in proxy[s] for v in variants))
    if not scenes:
        raise ValueError("no scene has every variant finished under both profiles")
    rows = []
    for s in scenes:
        for v in variants:
            rows.append({"scene": s, "variant": v, "standard_psnr": round(standard[s][v], 4),
                         "proxy_psnr": round(proxy[s][v], 4),
                         "standard_minus_reference": round(standard[s][v] - standard[s][reference], 4),
                         "proxy_minus_reference": round(proxy[s][v] - proxy[s][reference], 4)})
    pairs = [(r["standard_minus_reference"], r["proxy_minus_reference"]) for r in rows if r["variant"] in candidates]
    std_d, px_d = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
    rho = float(spearmanr(std_d, px_d).statistic) if len(pairs) > 2 and std_d.std() > 0 and px_d.std() > 0 else None
    alike = [np.sign(a[0] - b[0]) == np.sign(a[1] - b[1]) for a, b in combinations(pairs, 2)]
    same_best = sum(max(variants, key=standard[s].get) == max(variants, key=proxy[s].get) for s in scenes)
    mean = {p: {v: float(np.mean([d[s][v] for s in scenes])) for v in variants}
            for p, d in (("standard", standard), ("proxy", proxy))}
    summary = {"scenes": len(scenes), "candidates": len(candidates), "spearman_of_differences": rho,
               "pairs_ordered_alike": float(np.mean(alike)) if alike else None,
               "scenes_with_the_same_best": same_best,
               "standard_ranking": sorted(variants, key=lambda v: -mean["standard"][v]),
               "proxy_ranking": sorted(variants, key=lambda v: -mean["proxy"][v]), "means": mean}
    return rows, summary


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python benchmarks/proxy_ranking.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--standard", type=Path, required=True, help="tables folder trained at the standard profile")
    p.add_argument("--proxy", type=Path, required=True, help="the same plan at the shorter profile")
    p.add_argument("--variants", required=True, help="comma list, the reference (Full) first")
    p.add_argument("--split", choices=("val", "test"), default="val")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--digest", help="the trainer version to read on both sides (a prefix; a tables folder that "
                                    "keeps an earlier trainer's runs needs it)")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/rules/proxy_ranking.csv"))
    args = p.parse_args(argv)
    variants = [v for v in args.variants.split(",") if v]
    if len(variants) < 2:
        print("proxy_ranking: error: --variants: the reference and at least one candidate", file=sys.stderr)
        return 2
    try:
        s_digest, standard = scores(args.standard, variants, args.split, args.seed, args.digest)
        p_digest, proxy = scores(args.proxy, variants, args.split, args.seed, args.digest)
        rows, summary = compare(standard, proxy, variants)
    except (ValueError, FileNotFoundError) as exc:
        print(f"proxy_ranking: error: {exc}", file=sys.stderr)
        return 2
    if s_digest != p_digest:
        print(f"proxy_ranking: error: {args.standard} holds trainer {s_digest[:8]} and {args.proxy} {p_digest[:8]}: "
              "compare one trainer", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_rows_csv(args.out, rows)
    rho = summary["spearman_of_differences"]
    print(f"trainer {s_digest[:8]}, {args.split} views, seed {args.seed}: {summary['scenes']} scenes, "
          f"{summary['candidates']} candidate(s) against {variants[0]}")
    print(f"  Spearman of the differences from {variants[0]}: {'n/a' if rho is None else f'{rho:.2f}'}; "
          f"pairs ordered alike: {summary['pairs_ordered_alike']:.0%}; "
          f"same best variant on {summary['scenes_with_the_same_best']} of {summary['scenes']} scenes")
    for prof in ("standard", "proxy"):
        ranked = ", ".join(f"{v} {summary['means'][prof][v]:.2f}" for v in summary[f"{prof}_ranking"])
        print(f"  {prof} ranking by the mean: {ranked}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
