"""Renders a brick-textured box face-on from the front (a vertical face) and from above, with
the generator's own RGB material, and writes the two images' luminance as JSON.
Run in a subprocess: python texture_faces.py OUT.json
"""
import json
import os
import sys

import bpy  # noqa: F401
import numpy as np

from blender import materials, render
from blender.job import CameraJob, ImageSize, MaterialJob, TextureJob
from blender.recipes import RECIPES
from blender.scene import BuiltScene, build_camera, reset
from contracts.imageio import read_png

BRICK = MaterialJob(name="brick", base_color=(0.6, 0.22, 0.15), roughness=0.8, metallic=0.0,
                    texture=TextureJob(kind="brick", scale=1.0, color2=(0.45, 0.18, 0.12), detail=0.0,
                                       mortar_color=(0.95, 0.95, 0.95)),
                    thermal_curve=((0.0, 50.0),))
#: Cameras 4 m from the face: on -Y looking along +Y at the face y = -1, and above looking down.
VIEWS = {
    "front": [[1, 0, 0, 0], [0, 0, -1, -5.0], [0, 1, 0, 1.0], [0, 0, 0, 1]],
    "top": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 6.0], [0, 0, 0, 1]],
}


def main() -> None:
    out = sys.argv[1]
    reset()
    box = RECIPES["box"]("box", {"dimensions": (2.0, 2.0, 2.0), "bevel": 0.0})
    box.data.materials.append(materials.rgb_surface(BRICK))
    materials.world("world.rgb", (1.0, 1.0, 1.0), 1.0)
    build_camera()
    built = BuiltScene(surfaces={"box": ("brick.rgb", "brick.rgb")})
    render.configure_engine(seed=0, threads=1)
    bpy.context.scene.world = bpy.data.worlds["world.rgb"]
    camera = ImageSize(48, 48, 0.6 * 48 * 4 / 2)  # the 2 m face fills the middle 60%
    settings = CameraJob(render=camera, depth=camera, samples=16, clean_samples=16, denoise="none",
                         volume_step_rate=1.0, frames=())
    images = {}
    for view, c2w in VIEWS.items():
        render.apply_pass(render.pass_setup("rgb", "clean", settings), built, camera)
        path = os.path.join(os.path.dirname(out), f"{view}.png")
        render.render_to(path, c2w, 1)
        images[view] = (read_png(path).astype(np.float64) / 255).mean(axis=-1).tolist()
    with open(out, "w") as fh:
        json.dump(images, fh)
    sys.stdout.flush()
    os._exit(0)


main()
