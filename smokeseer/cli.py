"""``train-and-evaluate DATASET --mode MODE --out RUN_DIR [--profile quick|paper]``.

Bad input prints one error line and exits 2; a diverged run (NaN) exits 1 after writing a
checkpoint and a failed metrics.json.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from smokeseer.config import MODES, PROFILES
from smokeseer.data import DatasetError
from smokeseer.trainutil import NaNDetected


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train-and-evaluate", description=__doc__.splitlines()[0])
    p.add_argument("dataset", type=Path, help="dataset written by generate-scene, or a real capture")
    p.add_argument("--mode", default="full", choices=MODES)
    p.add_argument("--out", type=Path, required=True, help="run directory (resumed if it has checkpoints)")
    p.add_argument("--profile", default="quick", choices=PROFILES)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda")
    p.add_argument("--iterations-stage2", type=int, help="override the profile's Stage 2 iterations")
    p.add_argument("--iterations-stage3", type=int, help="override the profile's Stage 3 iterations")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any config field by dotted key, e.g. stage3.smoke_points=500")
    p.add_argument("--no-progress", action="store_true", help="hide the tqdm bars")
    return p


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    ov: dict[str, Any] = {"device": args.device}
    if args.iterations_stage2 is not None:
        ov["stage2.iterations"] = args.iterations_stage2
    if args.iterations_stage3 is not None:
        ov["stage3.iterations"] = args.iterations_stage3
    if args.no_progress:
        ov["progress"] = False
    for item in args.set:
        if "=" not in item:
            raise ValueError(f"--set: expected KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        ov[key.strip()] = json.loads(value) if value.strip().startswith("[") else value
    return ov


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from smokeseer.api import train_and_evaluate

    try:
        doc = train_and_evaluate(args.dataset, args.out, mode=args.mode, profile=args.profile,
                                 seed=args.seed, overrides=_overrides(args))
    except (DatasetError, ValueError, FileNotFoundError) as exc:
        print(f"train-and-evaluate: error: {exc}", file=sys.stderr)
        return 2
    except NaNDetected as exc:
        print(f"train-and-evaluate: diverged: {exc}; checkpoint in {args.out / 'checkpoints'}", file=sys.stderr)
        return 1
    m = doc["metrics"]
    print(json.dumps({"status": doc["status"], "psnr": m["psnr"], "psnr_input": m["psnr_input"],
                      "ssim": m["ssim"], "out": str(args.out)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
