"""Full at one seed on a list of datasets, through one resumable `regenerate-tables` call: the
shared part of the benchmarks that train the same runs twice under one change (the float setup,
the input's noise) and compare them scene by scene."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from contracts.atomic import write_rows_csv


def add_arguments(p: argparse.ArgumentParser, scenes: str, csv: str | None) -> None:
    """The options every such benchmark takes (its own go beside them). ``csv`` None: the
    benchmark picks its CSV after parsing, from its other options, unless ``--csv`` names one."""
    p.add_argument("--scenes", default=scenes)
    p.add_argument("--datasets", type=Path, default=Path("data/standard"))
    p.add_argument("--profile", default="standard")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--csv", type=Path, default=None if csv is None else Path(csv))
    p.add_argument("--compare-only", action="store_true", help="train nothing; compare what has finished")


def scenes_of(args: argparse.Namespace, prog: str) -> list[str] | None:
    """The scenes asked for, or None after one error line when one has no dataset."""
    scenes = [s for s in args.scenes.split(",") if s]
    missing = [s for s in scenes if not (args.datasets / s / "dataset.json").is_file()]
    if missing:
        print(f"{prog}: error: {args.datasets}: no dataset for {', '.join(missing)}", file=sys.stderr)
        return None
    return scenes


def tables_command(datasets: dict[str, Path], profile: str, seed: int, workers: int, out: Path,
                   candidates: tuple[str, ...] = ()) -> list[str]:
    """The `regenerate-tables` call that trains Full (and the rule ``candidates`` beside it) at
    ``seed`` on each named dataset into ``out``."""
    cmd = [sys.executable, "-m", "eval.harness_cli", "--profile", profile, "--workers", str(workers),
           "--scenes", ",".join(datasets), "--methods", "full", "--seeds", f"{seed},", "--no-ablations",
           "--out", str(out)]
    if candidates:
        cmd += ["--candidates", ",".join(candidates)]
    for name, path in datasets.items():
        cmd += ["--dataset", f"{name}={path}"]
    return cmd


def validation_psnr(run: Path) -> float | None:
    value = (json.loads((run / "metrics.json").read_text()).get("validation") or {}).get("psnr")
    return None if value is None else float(value)


def write_pairs(prog: str, csv: Path, rows: list[dict[str, Any]], sides: tuple[str, str], difference: str,
                missing: str) -> bool:
    """Write the per-scene CSV of two sides' PSNRs (``sides``: the two row keys' prefixes, e.g.
    ("default", "avx2")) and print a line per scene; False after one error line (``missing``) when
    no scene has both."""
    if not rows:
        print(f"{prog}: error: {missing}", file=sys.stderr)
        return False
    csv.parent.mkdir(parents=True, exist_ok=True)
    write_rows_csv(csv, rows)
    a, b = sides
    for r in rows:
        print(f"{r['scene']:<11} {a} {r[f'{a}_psnr']:6.2f}  {b} {r[f'{b}_psnr']:6.2f}  difference {r[difference]:+.3f} dB")
    return True
