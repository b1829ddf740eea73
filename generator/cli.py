"""`generate-scene`: build, bake and render a smoke scene into a dataset, or validate one."""
from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path

from contracts.errors import DatasetError
from generator.errors import GeneratorError
from generator.presets import list_presets

log = logging.getLogger("generate-scene")


def parse_size(text: str) -> tuple[int, int]:
    """`64x48` or `64` (square) to (width, height)."""
    try:
        parts = [int(p) for p in text.lower().split("x")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}")
    return parts[0], parts[1]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="generate-scene",
        description="Generate a paired RGB + thermal smoke dataset with Blender and Mantaflow.")
    p.add_argument("spec", nargs="?", type=Path, help="scene spec YAML (or use --preset or --random)")
    p.add_argument("--preset", help="a built-in scene (see --list-presets)")
    p.add_argument("--random", type=int, metavar="SEED",
                   help="draw a scene from SEED (docs/generator.md, 'The scene sampler'); its scene.yaml "
                        "regenerates it")
    p.add_argument("--set", action="append", default=[], metavar="AXIS=VALUE",
                   help="with --random: pin a sampler axis to a value or a range LO:HI, e.g. smoke.particles=soot, "
                        "fire=false, optical_depth=0.5:2")
    p.add_argument("--print-spec", action="store_true",
                   help="print the scene spec (drawn, with the size options applied) as YAML and exit")
    p.add_argument("--out", type=Path, help="output dataset folder")
    p.add_argument("--list-presets", action="store_true", help="list the built-in scenes and exit")
    p.add_argument("--validate", type=Path, metavar="DIR", help="check a dataset against docs/dataset-format.md")
    p.add_argument("--update-stats", type=Path, nargs="+", metavar="DIR",
                   help="recompute the statistics in each dataset's dataset.json from its files (no rendering)")
    p.add_argument("--refresh", action="store_true",
                   help="--out holds this scene's dataset but for ground truth (a pass such as rgb.shadowed, or clean "
                        "passes at fewer samples): render only that and swap it in")
    p.add_argument("--frames", type=int, help="number of RGB frames")
    p.add_argument("--resolution", type=parse_size, help="RGB resolution, WIDTHxHEIGHT")
    p.add_argument("--thermal-resolution", type=parse_size, help="thermal sensor resolution, WIDTHxHEIGHT")
    p.add_argument("--samples", type=int, help="Cycles samples per RGB pixel (also caps thermal samples)")
    p.add_argument("--sim-resolution", type=int, help="Mantaflow voxels along the domain's longest side")
    p.add_argument("--seed", type=int, help="seed for the renderer and sensor noise")
    p.add_argument("--passes", help="e.g. 'rgb', 'thermal', 'rgb.smoky,rgb.clean,thermal.depth'")
    p.add_argument("--density-scale", type=float, metavar="K",
                   help="scale every smoke coefficient by K: opacity 1-(1-a)^K, 0 = no smoke (default: the spec's)")
    p.add_argument("--bake-cache", type=Path, metavar="DIR",
                   help="keep the Mantaflow bake in DIR and reuse a finished one of the same simulation")
    p.add_argument("--threads", type=int, help="render threads (default: all cores)")
    p.add_argument("--force", action="store_true", help="replace an existing output folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    if args.list_presets:
        for name in list_presets():
            print(name)
        return 0
    if args.validate:
        from contracts.dataset_format import validate_dataset

        meta = validate_dataset(args.validate)
        frames = ", ".join(f"{m}: {', '.join(p)}" for m, p in meta["passes"].items() if p)
        print(f"{args.validate}: valid {meta['format']} v{meta['format_version']} (scene {meta['scene']}; {frames})")
        return 0
    if args.update_stats:
        from generator.dataset_stats import update_stats

        for root in args.update_stats:
            views = update_stats(root).get("test_views", {})
            print(f"{root}: statistics updated (test views: RGB optical depth {views.get('rgb_optical_depth')}, "
                  f"unrecoverable share {views.get('unrecoverable_share')})")
        return 0
    if sum(x is not None for x in (args.spec, args.preset, args.random)) != 1:
        parser.error("give exactly one of SPEC.yaml, --preset NAME or --random SEED")
    if args.set and args.random is None:
        parser.error("--set pins the axes of a drawn scene: use it with --random SEED")
    from generator.api import random_spec, refresh, resolve_spec
    from generator.pipeline import generate
    from generator.spec import Overrides

    overrides = Overrides(frames=args.frames, resolution=args.resolution, thermal_resolution=args.thermal_resolution,
                          samples=args.samples, sim_resolution=args.sim_resolution, seed=args.seed,
                          passes=args.passes, density_scale=args.density_scale)
    if args.random is not None:
        spec, source = random_spec(args.random, args.set, overrides)
    else:
        spec, source = resolve_spec(args.spec or args.preset, overrides)
    if args.print_spec:
        sys.stdout.write(spec.to_yaml())
        return 0
    if args.out is None:
        parser.error("--out DIR is required")
    if args.refresh:
        out = refresh(spec, source, args.out, show_progress=not args.quiet, threads=args.threads,
                      bake_store=args.bake_cache)
    else:
        out = generate(spec, args.out, source=source, force=args.force, show_progress=not args.quiet,
                       threads=args.threads, bake_store=args.bake_cache)
    print(out)
    return 0


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled exactly like Ctrl-C: the worker stops, the staging folder stays resumable."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated()


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    parser = build_parser()
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        return _run(args, parser)
    except (GeneratorError, DatasetError) as exc:
        print(f"generate-scene: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print("generate-scene: interrupted; run the same command again to resume", file=sys.stderr)
        return 128 + (signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT)


if __name__ == "__main__":
    sys.exit(main())
