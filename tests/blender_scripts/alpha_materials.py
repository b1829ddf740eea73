"""Renders the demo's RGB smoke opacity at its first frame three ways with the generator's own
job, scene builder and passes: through the scattering smoke material at many samples (the
reference: Cycles ends a sample that scatters, so it converges slowly), and through the
extinction-as-absorption material the opacity pass uses, at 4 samples and at 1; writes the
three alpha images as JSON.
Run in a subprocess: python alpha_materials.py OUT.json WORK_DIR
"""
import json
import os
import sys
from dataclasses import replace
from pathlib import Path

import bpy  # noqa: F401

from blender import render
from blender import scene as scene_mod
from blender.job import ImageSize
from blender.manta_repair import repair_manta_hierarchy
from generator.api import resolve_spec
from generator.assets import load_manifest
from generator.job import make_job, make_plan, resolve_asset_materials
from generator.postprocess import read_alpha

RENDERS = (("scattering_1024", "smoke.rgb", 1024), ("extinction_4", "smoke.rgb.extinction", 4),
           ("extinction_1", "smoke.rgb.extinction", 1))


def main() -> None:
    out, work = sys.argv[1], Path(sys.argv[2])
    repair_manta_hierarchy()
    spec, source = resolve_spec("demo")
    spec = resolve_asset_materials(replace(spec, frames=1), load_manifest(), source)
    job = make_job(spec, make_plan(spec), load_manifest(), source, work, 2)
    built = scene_mod.build(job)
    scene_mod.bake(built.domain)
    scene_mod.add_interpolation_twin(built)
    render.configure_engine(seed=0, threads=2)
    camera = replace(job.cameras["rgb"], render=ImageSize(32, 24, job.cameras["rgb"].render.fl_x / 2))
    frame = camera.frames[0]
    render.select_modality("rgb", built)
    images = {}
    for label, material, samples in RENDERS:
        setup = replace(render.pass_setup("rgb", "smoke_alpha", camera), samples=samples, smoke_material=material)
        render.apply_pass(setup, built, camera.render)
        render.show_smoke_state(built, True, 0.0, 1.0)
        path = str(work / f"{label}.exr")
        render.render_to(path, frame.c2w, frame.blender_frame)
        images[label] = read_alpha(Path(path)).tolist()
    with open(out, "w") as fh:
        json.dump({"pass_material": render.pass_setup("rgb", "smoke_alpha", camera).smoke_material, **images}, fh)
    sys.stdout.flush()
    os._exit(0)


main()
