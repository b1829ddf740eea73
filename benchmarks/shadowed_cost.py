"""What the shadowed ground truth (`rgb.shadowed`) costs beside the clean pass it is made like.

    python benchmarks/shadowed_cost.py [--scene house] [--frames 2] [--repeats 3]

Renders the scene's first RGB frames at the `standard` profile's size, the clean pass alone and
the shadowed pass alone, alternately, `--repeats` times each, each into a dataset of its own (the
bake is kept in a bake store, so only the first shadowed render bakes). The seconds per frame are
the worker's (`timings_s.render`: the renders alone, not the scene load). Both passes render at the
camera's `clean_samples`; they differ by the smoke domain, present for every ray but the camera's
in the shadowed pass. Prints the best per-frame time of each pass, their ratio, and the load
average around each render; writes benchmarks/results/shadowed_cost.csv.
"""
from __future__ import annotations

import argparse
import os
import tempfile
from dataclasses import replace
from pathlib import Path

from contracts.atomic import write_rows_csv
from contracts.dataset_format import DATASET_FILE, load_json
from generator.api import resolve_spec
from generator.pipeline import generate
from generator.profiles import get_profile
from generator.spec import parse_passes

RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="house")
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    spec, source = resolve_spec(args.scene, replace(get_profile("standard").overrides, frames=args.frames))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "bakes"
        for repeat in range(args.repeats):
            for name in ("clean", "shadowed"):
                load_before = os.getloadavg()[0]
                out = generate(replace(spec, passes=parse_passes(f"rgb.{name}", "benchmark")),
                               Path(tmp) / f"{name}{repeat}", source=source, force=True, show_progress=False,
                               bake_store=store)
                seconds = load_json(out / DATASET_FILE)["timings_s"]["render"][f"rgb.{name}"]
                rows.append({"scene": args.scene, "pass": name, "repeat": repeat, "frames": args.frames,
                             "samples": spec.rig.rgb.clean_samples, "seconds_per_frame": round(seconds, 3),
                             "load_before": round(load_before, 2), "load_after": round(os.getloadavg()[0], 2)})
                print(rows[-1], flush=True)
    best = {name: min(r["seconds_per_frame"] for r in rows if r["pass"] == name) for name in ("clean", "shadowed")}
    print(f"{args.scene}: best of {args.repeats}, seconds per RGB frame at {spec.rig.rgb.clean_samples} samples: "
          f"clean {best['clean']:.2f}, shadowed {best['shadowed']:.2f}, ratio {best['shadowed'] / best['clean']:.2f}")
    write_rows_csv(RESULTS / "shadowed_cost.csv", rows)


if __name__ == "__main__":
    main()
