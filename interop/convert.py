"""``convert-dataset SRC --to FORMAT --out DIR``: our dataset (or anything ``train-and-evaluate``
reads) in the official SmokeSeer layouts or nerfstudio's.

The output is staged in a hidden sibling of DIR and renamed into place at the end, so a failed
conversion leaves nothing at DIR. Bad input prints one line and exits 2.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
from pathlib import Path

from contracts.errors import DatasetError
from interop.layouts import SPLITS, TARGETS, WRITERS, Conversion, prepare, sidecar
from scenes.load import load_scene
from scenes.official_layouts import SIDECAR

log = logging.getLogger("convert-dataset")


def check_output(out: Path, target: str, split: str) -> None:
    """Refuse what the target's reader would misread, before any work is done."""
    if out.exists():
        raise ValueError(f"--out {out}: already exists; choose a new folder")
    if target in ("smokeseer-blender", "smokeseer-colmap") and "." in out.name:
        raise ValueError(f"--out {out}: the folder name contains a dot; the official SmokeSeer reader splits "
                         "paths at the first dot, so use a name without one")
    if target == "smokeseer-colmap" and split == "source":
        raise ValueError("--split source: the COLMAP layout cannot hold a split (the official reader holds out "
                         "every 8th image by name); use --split official")


def convert(src: Path, target: str, out: Path, split: str = "official", points: bool = False) -> Conversion:
    """Write ``src`` as ``target`` at ``out``; returns what was done, notes included."""
    if target not in TARGETS:
        raise ValueError(f"--to: {target!r} is not one of {', '.join(TARGETS)}")
    if split not in SPLITS:
        raise ValueError(f"--split: {split!r} is not one of {', '.join(SPLITS)}")
    out = Path(out)
    check_output(out, target, split)
    scene = load_scene(Path(src), max_width=0, all_ground_truth=True)
    conv = Conversion(target=target, split=split, points=points or target == "smokeseer-colmap")
    frames, origin = prepare(scene, conv)
    stage = out.parent / f".{out.name}.partial-{os.getpid()}"
    if stage.exists():
        shutil.rmtree(stage)
    try:
        stage.mkdir(parents=True)
        WRITERS[target](scene, frames, stage, conv)
        (stage / SIDECAR).write_text(json.dumps(sidecar(scene, conv, origin), indent=2))
        os.rename(stage, out)
    finally:
        if stage.exists():
            shutil.rmtree(stage)
    return conv


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="convert-dataset", description=__doc__.splitlines()[0])
    p.add_argument("src", type=Path, help="dataset written by generate-scene, a real capture, or an official layout")
    p.add_argument("--to", required=True, choices=TARGETS, help="layout to write (docs/interop.md)")
    p.add_argument("--out", type=Path, required=True, help="new folder to create (no dots in its name)")
    p.add_argument("--split", default="official", choices=SPLITS,
                   help="official: every 8th RGB frame by time is a test view, as the official reader's --eval; "
                        "source: keep the source's train/test split (Blender layout and nerfstudio only)")
    p.add_argument("--points", action="store_true",
                   help="also write sparse_colmap/points3D.bin in the Blender layout (the COLMAP layout always has "
                        "points); from the source's ground-truth depth when it has depth")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s convert-dataset: %(message)s", datefmt="%H:%M:%S")
    try:
        conv = convert(args.src, args.to, args.out, args.split, args.points)
    except (DatasetError, ValueError, OSError) as exc:
        print(f"convert-dataset: error: {exc}", file=sys.stderr)
        return 2
    for note in conv.notes:
        log.info(note)
    log.info("wrote %s as %s", args.out, args.to)
    return 0


if __name__ == "__main__":
    sys.exit(main())
