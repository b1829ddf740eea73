"""How much of a dense scene's darkening is the smoke's shadow, which no line-of-sight
de-smoking can undo? Renders the RGB test frames of a baked standard scene (a copy of its
staging folder) three ways with the generator's own pass setup: clean (no smoke), smoky, and
"lit through smoke" (the clean pass with the smoke present for light and shadow rays but
invisible to camera rays, Cycles' visible_camera off). Run with the project's .venv python:
    python benchmarks/shadow_pass.py STAGING_COPY OUT_DIR [STEM,STEM,...]
then `python benchmarks/shadow_ceiling.py OUT_DIR` for the PSNRs. STAGING_COPY is a copy of a
scene's `.SCENE.partial` folder (scene.blend, scene.built.json, job.json, cache/) after its bake.
"""
import json
import sys
from pathlib import Path

import bpy

from blender import render
from blender.manta_repair import repair_manta_hierarchy
from blender.job import WorkerJob
from blender.scene import BuiltScene, prepare_for_rendering

staging, out = Path(sys.argv[1]), Path(sys.argv[2])
job = WorkerJob.read(staging / "job.json")
repair_manta_hierarchy()
bpy.ops.wm.open_mainfile(filepath=str(staging / "scene.blend"))
built = BuiltScene.from_json(json.loads((staging / "scene.built.json").read_text()))
for obj in bpy.data.objects:  # the bake's cache is read from the copy, wherever the job had it
    for mod in obj.modifiers:
        if mod.type == "FLUID" and mod.fluid_type == "DOMAIN":
            mod.domain_settings.cache_directory = str(staging / "cache")
prepare_for_rendering(built)
render.configure_engine(job.seed, 1)
camera = job.cameras["rgb"]
render.select_modality("rgb", built)
stems = sys.argv[3].split(",") if len(sys.argv) > 3 else None
frames = [f for f in camera.frames if (stems is None and int(f.stem) % 8 == 4) or (stems and f.stem in stems)]
domains = [bpy.data.objects[n] for n in (built.domain, built.domain_next) if n]
for kind in ("lit_through_smoke", "clean", "smoky"):
    setup = render.pass_setup("rgb", "smoky" if kind == "smoky" else "clean", camera)
    render.apply_pass(setup, built, camera.render)
    for d in domains:
        d.visible_camera = kind != "lit_through_smoke"
    (out / kind).mkdir(parents=True, exist_ok=True)
    for f in frames:
        path = out / kind / f"{f.stem}.png"
        if path.exists():
            continue
        render.show_smoke_state(built, kind != "clean", f.next_weight, 1.0)
        render.render_to(str(path), f.c2w, f.blender_frame)
        print(kind, f.stem, flush=True)
