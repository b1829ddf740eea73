"""Renders the demo's smoke opacity at two consecutive baked frames, halfway between them, with
only the interpolation twin shown, and with the domain at full weight beside its twin shown at
weight 0 (the twin's box must not hide the domain's smoke), using the generator's own job, scene builder, twin and
render passes; writes the five alpha images as JSON. The first frame looks from START_DEG on the
demo's orbit.
Run in a subprocess: python interpolated_smoke.py OUT.json WORK_DIR START_DEG
"""
import json
import os
import sys
from dataclasses import replace
from pathlib import Path

import bpy

from blender import render
from blender import scene as scene_mod
from blender.manta_repair import repair_manta_hierarchy
from generator.api import resolve_spec
from generator.assets import load_manifest
from generator.job import make_job, make_plan, resolve_asset_materials
from generator.postprocess import read_alpha

#: (label, baked frame, weight of the next baked frame, twin shown even at weight 0)
STATES = (("start", 0, 0.0, False), ("end", 1, 0.0, False), ("halfway", 0, 0.5, False), ("twin_only", 0, 1.0, False),
          ("start_twin_shown", 0, 0.0, True))


def main() -> None:
    out, work, start_deg = sys.argv[1], Path(sys.argv[2]), float(sys.argv[3])
    repair_manta_hierarchy()
    spec, source = resolve_spec("demo")
    manifest = load_manifest()
    trajectory = replace(spec.rig.trajectory, start_deg=start_deg)
    spec = replace(spec, frames=2, rig=replace(spec.rig, trajectory=trajectory))
    spec = resolve_asset_materials(spec, manifest, source)
    job = make_job(spec, make_plan(spec), manifest, source, work, 1)
    built = scene_mod.build(job)
    scene_mod.bake(built.domain)
    scene_mod.add_interpolation_twin(built)
    render.configure_engine(seed=0, threads=1)
    camera = replace(job.cameras["rgb"], samples=64)
    frame = camera.frames[0]
    render.select_modality("rgb", built)
    setup = render.pass_setup("rgb", "smoke_alpha", camera)
    render.apply_pass(setup, built, camera.render)
    images = {}
    for label, offset, weight, twin_shown in STATES:
        path = str(work / f"{label}.exr")
        render.show_smoke_state(built, True, weight, 1.0)
        if twin_shown:
            bpy.data.objects[built.domain_next].hide_render = False
        render.render_to(path, frame.c2w, frame.blender_frame + offset)
        images[label] = read_alpha(Path(path)).tolist()
    with open(out, "w") as fh:
        json.dump(images, fh)
    sys.stdout.flush()
    os._exit(0)


main()
