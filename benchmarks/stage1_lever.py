"""Usage: python benchmarks/stage1_lever.py DATASET --out RUN_DIR [--seed 0] [--profile standard]
          [--threads 1]

What the rig's lever arm costs Table 1's "Full, Stage 1 from images" on a generated dataset.
That row (`--set stage1=estimate --set poses=sfm`) poses the RGB frames by SfM and the thermal
frames from the rig, but SfM poses have no metric scale, so the trainer applies the lever arm
only when `rig.metres_per_unit` is given (a capture's capture.json can say it; a generated
dataset does not) and otherwise puts the thermal centres on the RGB ones, as its log says. On an
object-sized scene the 7 cm lever is several per cent of the scene.

This trains the same run with the lever applied, at the scale the trainer already reads off the
dataset's poses to score depth (the similarity of the SfM camera centres onto the true ones,
`SceneData.score_depth_scale`): an oracle scale, standing in for a measured distance or GNSS on
a real rig. Everything else is the row's run, so the difference between the two is the cost of
the missing lever. A diagnostic, not a method: `lever.json` in the run folder says what was
changed, beside the trainer's usual files.
"""
from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset", type=Path)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--profile", default="standard")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(args.threads)
    import torch

    from contracts.atomic import write_json
    from smokeseer import api
    from smokeseer.stage1 import poses_from_images

    torch.set_num_threads(args.threads)
    applied: dict = {}
    unscaled = poses_from_images._thermal

    def thermal_with_lever(scene, rig):
        if rig is not None:
            rig = replace(rig, metres_per_unit=float(scene.score_depth_scale))
            applied.update(metres_per_unit=rig.metres_per_unit, lever_arm_m=rig.lever_arm_m.tolist())
        return unscaled(scene, rig)

    poses_from_images._thermal = thermal_with_lever
    try:
        doc = api.train_and_evaluate(args.dataset, args.out, "full", args.profile, args.seed,
                                     {"stage1": "estimate", "poses": "sfm"})
    except ValueError as exc:  # DatasetError and SfmError among them: one line naming the input
        print(f"stage1_lever: error: {exc}", file=sys.stderr)
        return 2
    write_json(args.out / "lever.json", {
        "what": "Full, Stage 1 from images, with the rig's lever arm applied at the scale of the SfM "
                "centres' similarity onto the dataset's poses (an oracle metric scale)",
        **applied, "psnr": doc["metrics"]["psnr"], "seed": args.seed, "profile": args.profile})
    print(f"{args.dataset.name}: test PSNR {doc['metrics']['psnr']:.2f} dB with the lever applied "
          f"({applied.get('metres_per_unit', float('nan')):.4g} m per SfM unit)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
