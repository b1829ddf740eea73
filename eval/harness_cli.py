"""`regenerate-tables`: one command from presets to Table 1, Table 2, figures and report.

It prints its plan (runs, cached runs, datasets, estimated time) before starting; --dry-run
stops there. Exit codes: 0 all runs ok; 1 tables written but some runs failed (see
report.md); 2 bad input (one error line on stderr).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from eval.adopt import adopt_runs
from eval.harness import DEFAULT_OUT, HarnessConfig, regenerate
from eval.finished_runs import finished_runs
from eval.runs import ABLATIONS, CANDIDATES, METHODS, VARIANTS
from eval.settings import default_workers
from generator.cli import parse_size
from generator.profiles import get_profile
from contracts.set_items import parse_set_items
from smokeseer.config import LPIPS_NETS


def _list(s: str) -> list[str]:
    return [x.strip() for x in s.split(",") if x.strip()]


def parse_seeds(s: str) -> list[int]:
    """"3" means seeds 0, 1, 2; a comma list ("0,5" or "7,") names the seeds."""
    try:
        if "," in s:
            return [int(x) for x in _list(s)]
        n = int(s)
    except ValueError:
        raise ValueError(f"seeds: expected a count or a comma list of integers, got {s!r}") from None
    if n < 1:
        raise ValueError(f"seeds: count must be >= 1, got {n}")
    return list(range(n))


def _known_presets() -> list[str] | None:
    try:
        from generator.presets import list_presets
    except ImportError:
        return None
    return list(list_presets())


def parse_size_checked(text: str) -> tuple[int, int]:
    """The generator's size syntax, refused at parse time: a bad size would otherwise fail every run."""
    width, height = parse_size(text)
    if min(width, height) < 1:
        raise argparse.ArgumentTypeError(f"expected a positive WIDTHxHEIGHT, got {text!r}")
    return width, height


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="regenerate-tables", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT,
                   help=f"output folder; the cache lives here (default {DEFAULT_OUT}, git-ignored)")
    p.add_argument("--scenes", type=_list, default=None,
                   help="comma list of generator presets (default: every preset except demo)")
    p.add_argument("--methods", type=_list, default=list(METHODS), help=f"comma list of {', '.join(METHODS)}")
    p.add_argument("--ablations", action=argparse.BooleanOptionalAction, default=True,
                   help="also run Table 2's ablations")
    p.add_argument("--ablation-list", type=_list, default=None,
                   help=f"subset of {', '.join(ABLATIONS)} (default: every prior off, and the depth row that "
                        "differs from the profile's Full: w/o depth, or with depth where Full has none)")
    p.add_argument("--candidates", type=_list, default=[],
                   help=f"rule candidates to run beside Full, chosen on validation views: {', '.join(CANDIDATES)} "
                        "(docs/method.md, Decisions)")
    p.add_argument("--seeds", default="3", help="count N (seeds 0..N-1) or comma list (default 3)")
    p.add_argument("--profile", choices=("quick", "standard", "paper"), default="quick",
                   help="training profile of every run (quick: minutes on a CPU; standard: the benchmark scale, about 20 min a "
                        "run on one core; paper: the paper's schedule, GPU)")
    p.add_argument("--workers", type=int, default=default_workers(), help="parallel tasks (default: cores/2)")
    p.add_argument("--scheduler", default=None,
                   help='Dask scheduler address (tcp://host:8786), or "local" for a Dask LocalCluster; '
                        "default: a local process pool")
    p.add_argument("--device", default="cpu",
                   help="torch device the runs train on: cpu or cuda[:N] (recorded per run, not part of its cache "
                        "key; on CUDA the trainer rasterizes with gsplat where it is installed, else the torch backend)")
    p.add_argument("--dataset", action="append", default=[], metavar="SCENE=PATH",
                   help="use an existing dataset for a scene instead of generating it")
    p.add_argument("--dehazer", default="dcp", help="dehazer for the ImgDehaze baseline")
    p.add_argument("--iterations", type=int, default=None,
                   help="tiny budget: stage2/stage3 iterations (also sets stage3.test_every to a quarter)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="trainer override, dotted key, value read as YAML (as train-and-evaluate --set)")
    p.add_argument("--gen-profile", choices=("bench", "standard", "paper", "native"), default=None,
                   help="generator size profile for the scenes (default: bench with --profile quick, standard with "
                        "--profile standard, paper with --profile paper; native keeps each preset's own size); the flags below refine it")
    p.add_argument("--frames", type=int, default=None, help="generator override")
    p.add_argument("--resolution", type=parse_size_checked, default=None, help="generator override: RGB WIDTHxHEIGHT")
    p.add_argument("--thermal-resolution", type=parse_size_checked, default=None, help="generator override: WIDTHxHEIGHT")
    p.add_argument("--samples", type=int, default=None, help="generator override: Cycles samples")
    p.add_argument("--sim-resolution", type=int, default=None, help="generator override: Mantaflow voxels")
    p.add_argument("--gen-set", action="append", default=[], metavar="KEY=VALUE", help="other generator override")
    p.add_argument("--lpips-net", choices=LPIPS_NETS, default="alex", help="LPIPS backbone the trainer scores with")
    p.add_argument("--lpips-weights", default=None, help="backbone .pth (torchvision layout) or its folder")
    p.add_argument("--lpips-heads", default=None, help="LPIPS v0.1 heads .pth, or an lpips wheel")
    p.add_argument("--adopt-from", type=Path, default=None, metavar="DIR",
                   help="first adopt the finished runs of this plan found in another --out folder whose keys "
                        "differ only by the trainer's code digest (another Python); see docs/scale-out.md")
    p.add_argument("--digest", default=None, metavar="PREFIX",
                   help="with --finished-only: table the finished runs in --out of the trainer whose code digest "
                        "starts so (an earlier trainer's), in place of today's")
    p.add_argument("--dry-run", action="store_true", help="print the plan (runs, estimated time) and stop")
    p.add_argument("--finished-only", action="store_true",
                   help="write the tables from the runs already finished in --out, beside an invocation still "
                        "training there; generate, dehaze and train nothing (the rest are listed as pending)")
    return p


def config_from_args(args: argparse.Namespace) -> HarnessConfig:
    """Turn parsed flags into a validated HarnessConfig (ValueError names the bad flag)."""
    datasets = {k: Path(str(v)) for k, v in parse_set_items(args.dataset, "--dataset").items()}
    scenes = args.scenes
    presets = _known_presets()
    if scenes is None:
        if presets is None:
            raise ValueError("scenes: generator presets are unavailable; pass --scenes and --dataset")
        scenes = [s for s in presets if s != "demo"]
    for s in scenes:
        if s not in datasets and presets is not None and s not in presets:
            raise ValueError(f"scenes: unknown preset {s!r}; known: {', '.join(presets)}")
        if s not in datasets and presets is None:
            raise ValueError(f"scenes: cannot generate {s!r} (generator unavailable); pass --dataset {s}=PATH")
    extra = set(datasets) - set(scenes)
    if extra:
        raise ValueError(f"dataset: scene(s) {', '.join(sorted(extra))} not in --scenes")
    train = parse_set_items(args.set, "--set")
    if args.iterations is not None:
        if args.iterations < 1:
            raise ValueError(f"iterations: must be >= 1, got {args.iterations}")
        train.setdefault("stage2.iterations", args.iterations)
        train.setdefault("stage3.iterations", args.iterations)
        train.setdefault("stage3.test_every", max(1, args.iterations // 4))
    gen_profile = args.gen_profile or {"quick": "bench", "standard": "standard", "paper": "paper"}[args.profile]
    gen = {} if gen_profile == "native" else get_profile(gen_profile).kwargs()
    gen.update(parse_set_items(args.gen_set, "--gen-set"))
    for key in ("frames", "resolution", "thermal_resolution", "samples", "sim_resolution"):
        if getattr(args, key) is not None:
            gen[key] = getattr(args, key)
    digest = args.digest or ""
    if digest and args.finished_only:  # the full digest of the runs in --out (else validate() refuses it)
        digest = finished_runs(args.out, VARIANTS, digest)[0]
    cfg = HarnessConfig(
        out=args.out, scenes=scenes, methods=args.methods,
        ablations=args.ablation_list if args.ablations else [], candidates=args.candidates,
        seeds=parse_seeds(args.seeds),
        profile=args.profile, train_overrides=train, gen_overrides=gen, datasets=datasets,
        dehazer=args.dehazer, workers=args.workers, scheduler=args.scheduler,
        lpips_net=args.lpips_net, lpips_weights=args.lpips_weights, lpips_heads=args.lpips_heads,
        finished_only=args.finished_only, device=args.device,
        trainer_digest=digest,
    )
    from eval.dehaze import available_dehazers

    if cfg.dehazer not in available_dehazers():
        raise ValueError(f"dehazer: unknown {cfg.dehazer!r}, available: {', '.join(available_dehazers())}")
    cfg.validate()
    return cfg


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    try:
        cfg = config_from_args(args)
    except ValueError as exc:
        print(f"regenerate-tables: error: {exc}", file=sys.stderr)
        return 2
    if args.adopt_from is not None:
        if not (args.adopt_from / "runs").is_dir():
            print(f"regenerate-tables: error: adopt_from: {args.adopt_from} has no runs/ folder", file=sys.stderr)
            return 2
        for a in adopt_runs(cfg, args.adopt_from, dry_run=args.dry_run):
            verb = ("would adopt" if args.dry_run else "adopted") if a.adopted else "not adopted"
            print(f"[{verb}] {a.scene}/{a.variant}/seed {a.seed}" + (f" from {a.source}" if a.adopted else f": {a.reason}"),
                  file=sys.stderr)
    results, paths = regenerate(cfg, dry_run=args.dry_run)
    if args.dry_run:
        return 0
    failed = sum(r.status == "failed" for r in results)
    pending = sum(r.status == "pending" for r in results)
    print(f"wrote {len(paths)} files to {Path(cfg.out).resolve()}; {len(results) - failed - pending} runs ok, "
          f"{failed} failed" + (f", {pending} pending" if pending else ""))
    for name in ("table1.md", "table2.md"):
        if name in paths:
            print(Path(paths[name]).read_text())
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
