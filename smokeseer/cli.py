"""``train-and-evaluate DATASET --mode MODE --out RUN_DIR [--profile quick|standard|paper]``.

Bad input (options, settings that cannot train, the dataset, a damaged checkpoint, a RUN_DIR
another running process trains in) prints one error line and exits 2, and leaves nothing new in
RUN_DIR; a diverged run (NaN) exits 1 after writing the last good state to
checkpoints/stageN_nan.pt (stage2_rgb_nan.pt for the RGB Stage 2 of a two-surface run) and a
failed metrics.json; a loss that runs away (loss.divergence_factor) exits 1 with one line and a
metrics.json whose status is diverged, with no scores.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from contracts.errors import DatasetError
from contracts.set_items import parse_set_items
from smokeseer.config import LPIPS_NETS, MODES, PROFILES
from smokeseer.raster.extension import KernelBuildError
from smokeseer.train.divergence import StageDiverged
from smokeseer.train.util import NaNDetected


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train-and-evaluate", description=__doc__.splitlines()[0])
    p.add_argument("dataset", type=Path, help="dataset written by generate-scene, or a real capture")
    p.add_argument("--mode", default="full", choices=MODES,
                   help="method or ablation to train (default full; see docs/method.md)")
    p.add_argument("--out", type=Path, required=True, help="run directory (resumed if it has checkpoints)")
    p.add_argument("--profile", default="quick", choices=PROFILES,
                   help="quick: minutes on a CPU at reduced size; standard: the benchmark scale, about 20 min on one core with a "
                        "validation split; paper: the paper's 15k+15k schedule, for a GPU")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")
    p.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda")
    p.add_argument("--iterations-stage2", type=int, help="override the profile's Stage 2 iterations")
    p.add_argument("--iterations-stage3", type=int, help="override the profile's Stage 3 iterations")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any config field by dotted key, value read as YAML, e.g. stage3.smoke_points=500")
    p.add_argument("--lpips-net", choices=LPIPS_NETS, default=None, help="LPIPS backbone (default alex)")
    p.add_argument("--lpips-weights", default=None,
                   help="torchvision backbone .pth or its folder (default: $TORCH_HOME/hub/checkpoints)")
    p.add_argument("--lpips-heads", default=None, help="LPIPS v0.1 linear heads .pth, or an lpips wheel")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads for torch and the compiled rasterizer alike (default: OMP_NUM_THREADS, "
                        "else the core count); the rasterizer's output does not depend on it")
    p.add_argument("--no-progress", action="store_true", help="hide the tqdm bars")
    return p


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    ov: dict[str, Any] = {"device": args.device}
    for key, value in (("stage2.iterations", args.iterations_stage2), ("stage3.iterations", args.iterations_stage3),
                       ("lpips_net", args.lpips_net), ("lpips_weights", args.lpips_weights),
                       ("lpips_heads", args.lpips_heads)):
        if value is not None:
            ov[key] = value
    if args.no_progress:
        ov["progress"] = False
    ov.update(parse_set_items(args.set))
    return ov


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.threads is not None and args.threads < 1:
        print(f"train-and-evaluate: error: --threads: must be at least 1, got {args.threads}", file=sys.stderr)
        return 2
    import torch

    from smokeseer.api import train_and_evaluate

    if args.threads is not None:
        torch.set_num_threads(args.threads)

    try:
        doc = train_and_evaluate(args.dataset, args.out, mode=args.mode, profile=args.profile,
                                 seed=args.seed, overrides=overrides_from_args(args))
    except (DatasetError, ValueError, FileNotFoundError) as exc:
        print(f"train-and-evaluate: error: {exc}", file=sys.stderr)
        return 2
    except KernelBuildError as exc:
        print(f"train-and-evaluate: error: {exc}", file=sys.stderr)
        return 2
    except NaNDetected as exc:
        print(f"train-and-evaluate: diverged: {exc}; last good state in {exc.last_good}", file=sys.stderr)
        return 1
    except StageDiverged as exc:
        print(f"train-and-evaluate: diverged: {exc}; no scores written ({args.out / 'metrics.json'}: status "
              "diverged)", file=sys.stderr)
        return 1
    m = doc["metrics"]
    print(json.dumps({"status": doc["status"], "psnr": m["psnr"], "psnr_input": m["psnr_input"],
                      "ssim": m["ssim"], "out": str(args.out)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
