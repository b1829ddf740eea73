"""Renders a plate at known radiance behind a homogeneous LWIR slab, with the generator's
own thermal materials and render passes. Run in a subprocess:
python thermal_slab.py OUT.json L_SURF L_SMOKE K D...

Writes, per absorption coefficient K (1/m) and slab thickness D, the mean rendered radiance
(the plate through the slab plus the slab's own Kirchhoff emission at L_SMOKE) and the mean
LWIR alpha over the image centre.
"""
import json
import os
import sys

import bpy  # noqa: F401
import numpy as np

from blender import materials, render
from blender.job import CameraJob, ImageSize, MaterialJob, RgbSmokeJob, TextureJob, ThermalSmokeJob
from blender.scene import BuiltScene, build_camera, reset
from generator.postprocess import read_alpha, read_radiance


def main() -> None:
    out, l_surf, l_smoke = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
    cases = [(float(k), float(d)) for k, d in zip(sys.argv[4::2], sys.argv[5::2])]
    results = []
    for i, (k, d) in enumerate(cases):
        reset()
        spec = MaterialJob(name="plate", base_color=(0.5, 0.5, 0.5), roughness=0.5, metallic=0.0,
                           texture=TextureJob("none", 1.0, (0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 0.0)),
                           thermal_curve=((0.0, l_surf),))
        rgb, thermal = materials.rgb_surface(spec), materials.thermal_surface(spec)
        bpy.ops.mesh.primitive_plane_add(size=8.0)
        plate = bpy.context.object
        plate.name = "plate"
        plate.data.materials.append(rgb)
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, 1.0 + d / 2))
        slab = bpy.context.object
        slab.name = "slab"
        slab.scale = (8.0, 8.0, d)
        smoke = materials.thermal_smoke(ThermalSmokeJob(absorption_per_density=k, ambient_radiance=l_smoke, fire=None))
        materials.rgb_smoke(RgbSmokeJob(scatter_density=0.0, scatter_color=(1.0, 1.0, 1.0), absorb_density=0.0,
                                        absorb_color=(1.0, 1.0, 1.0), anisotropy=0.0, fire=None))
        tree = smoke.node_tree
        mul = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeMath")
        one = tree.nodes.new("ShaderNodeValue")
        one.outputs[0].default_value = 1.0  # a homogeneous slab: unit grid density everywhere
        tree.links.new(one.outputs[0], mul.inputs[0])
        materials.world("world.rgb", (0.5, 0.5, 0.5), 1.0)
        materials.world("world.thermal", (1.0, 1.0, 1.0), 0.0)
        build_camera()
        built = BuiltScene(surfaces={"plate": (rgb.name, thermal.name)}, domain="slab")
        render.configure_engine(seed=0, threads=2)
        render.select_modality("thermal", built)
        camera = ImageSize(16, 16, 160.0)  # ~6° FOV: every ray crosses the slab nearly normally
        c2w = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 5.0], [0, 0, 0, 1]]
        paths = {}
        settings = CameraJob(render=camera, depth=camera, samples=4, clean_samples=4, denoise="none",
                             volume_step_rate=1.0, frames=())
        for name in ("smoky", "smoke_alpha"):
            setup = render.pass_setup("thermal", name, settings)
            render.apply_pass(setup, built, camera)
            render.show_smoke_state(built, setup.smoke_visible, 0.0, 1.0)
            paths[name] = os.path.join(os.path.dirname(out), f"slab{i}_{name}.exr")
            render.render_to(paths[name], c2w, 1)
        centre = (slice(4, 12), slice(4, 12))
        results.append({"k": k, "d": d,
                        "radiance": float(read_radiance(paths["smoky"])[centre].mean()),
                        "alpha": float(read_alpha(paths["smoke_alpha"])[centre].mean())})
    with open(out, "w") as fh:
        json.dump(results, fh)
    sys.stdout.flush()
    os._exit(0)


main()
