"""Per-pass render configuration and a single render-to-file call.

Every pass of a modality renders the same baked scene: the passes differ only in
what is visible, which objects are holdouts, the film, the samples and the output.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import bpy
from mathutils import Matrix

from blender.job import CLEAN_SAMPLE_PASSES, SMOKE_PASSES, CameraJob, ImageSize
from contracts.atomic import atomic_path
from blender.materials import SMOKE_WEIGHT
from blender.scene import BuiltScene


@dataclass(frozen=True)
class PassSetup:
    """How one (modality, pass) renders: output format and which scene parts take part."""

    smoke_visible: bool
    holdout_surfaces: bool
    samples: int
    max_bounces: int
    point_filter: bool
    file_format: str  # "PNG" (8-bit sRGB) or "EXR" (float32, linear)
    depth_pass: bool = False
    denoise: str = "none"  # OpenImageDenoise guides, or none
    volume_step_rate: float = 1.0
    smoke_material: str = ""  # the smoke domain's material in this pass
    smoke_in_camera: bool = True  # False: the smoke shadows and lights the scene but camera rays pass it


#: Cycles' denoising inputs for each `denoise` setting of the spec.
DENOISE_INPUTS = {"color": "RGB", "albedo": "RGB_ALBEDO", "albedo_normal": "RGB_ALBEDO_NORMAL"}


def pass_setup(modality: str, name: str, camera: CameraJob) -> PassSetup:
    """Only the smoky image (what a real camera records) is denoised; ground truth stays exact.
    `shadowed` is the clean pass with the smoke in the scene for every ray but the camera's: the
    world under the smoke's shadow (and its glow and scattered light), with no smoke in view."""
    samples, step_rate = camera.samples, camera.volume_step_rate
    smoke = f"smoke.{modality}"
    if name == "depth":
        return PassSetup(False, False, 1, 0, True, "EXR", depth_pass=True, smoke_material=smoke)
    if name == "smoke_alpha":  # RGB: the extinction as absorption, so each sample carries the ray's transmittance
        return PassSetup(True, True, samples, 0, False, "EXR", volume_step_rate=step_rate,
                         smoke_material="smoke.rgb.extinction" if modality == "rgb" else smoke)
    fmt = "PNG" if modality == "rgb" else "EXR"
    bounces = 4 if modality == "rgb" else 0
    denoise = camera.denoise if name == "smoky" else "none"
    samples = camera.clean_samples if name in CLEAN_SAMPLE_PASSES else samples
    return PassSetup(name in SMOKE_PASSES, False, samples, bounces, False, fmt, denoise=denoise,
                     volume_step_rate=step_rate, smoke_material=smoke, smoke_in_camera=name != "shadowed")


def configure_engine(seed: int, threads: int) -> None:
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.seed = seed
    cycles.use_animated_seed = False
    cycles.use_denoising = False
    cycles.denoiser = "OPENIMAGEDENOISE"
    cycles.denoising_prefilter = "ACCURATE"
    cycles.denoising_quality = "HIGH"
    cycles.denoising_use_gpu = False
    cycles.use_adaptive_sampling = False
    cycles.volume_bounces = 1
    cycles.transparent_max_bounces = 8
    cycles.caustics_reflective = False
    cycles.caustics_refractive = False
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    scene.render.use_persistent_data = False
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    scene.render.use_file_extension = False
    scene.display_settings.display_device = "sRGB"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.sequencer_colorspace_settings.name = "sRGB"


def select_modality(modality: str, built: BuiltScene) -> None:
    """Swap every surface material and the world to the modality's set; lights only light RGB
    (the smoke's material is the pass's, `apply_pass`)."""
    scene = bpy.context.scene
    slot = 0 if modality == "rgb" else 1
    for obj_name, names in built.surfaces.items():
        obj = bpy.data.objects[obj_name]
        obj.data.materials.clear()
        obj.data.materials.append(bpy.data.materials[names[slot]])
    scene.world = bpy.data.worlds[f"world.{modality}"]
    if built.sun:
        bpy.data.objects[built.sun].hide_render = modality != "rgb"


def apply_pass(setup: PassSetup, built: BuiltScene, camera: ImageSize) -> None:
    scene = bpy.context.scene
    render, cycles = scene.render, scene.cycles
    render.resolution_x, render.resolution_y = camera.width, camera.height
    cam = scene.camera
    cam.data.lens = camera.fl_x * cam.data.sensor_width / camera.width
    cycles.samples = setup.samples
    cycles.max_bounces = setup.max_bounces
    cycles.diffuse_bounces = cycles.glossy_bounces = min(setup.max_bounces, 4)
    cycles.transmission_bounces = min(setup.max_bounces, 4)
    cycles.filter_width = 0.01 if setup.point_filter else 1.5
    cycles.volume_step_rate = setup.volume_step_rate
    cycles.use_denoising = setup.denoise != "none"
    if cycles.use_denoising:
        cycles.denoising_input_passes = DENOISE_INPUTS[setup.denoise]
    render.film_transparent = setup.holdout_surfaces
    if built.domain:  # the twin shares the domain's mesh, so its material too
        dom = bpy.data.objects[built.domain]
        dom.data.materials.clear()
        dom.data.materials.append(bpy.data.materials[setup.smoke_material])
    for obj_name in built.surfaces:
        bpy.data.objects[obj_name].is_holdout = setup.holdout_surfaces
    for obj_name in (built.domain, built.domain_next):
        if obj_name:
            bpy.data.objects[obj_name].visible_camera = setup.smoke_in_camera
    scene.view_layers[0].use_pass_z = setup.depth_pass
    settings = render.image_settings
    if setup.file_format == "PNG":
        settings.file_format = "PNG"
        settings.color_mode = "RGB"
        settings.color_depth = "8"
        settings.compression = 15
    else:
        settings.file_format = "OPEN_EXR_MULTILAYER" if setup.depth_pass else "OPEN_EXR"
        settings.color_mode = "RGBA"
        settings.color_depth = "32"
        settings.exr_codec = "ZIP"


def show_smoke_state(built: BuiltScene, visible: bool, next_weight: float, density_scale: float) -> None:
    """The smoke at a fractional frame: the domain shows the current baked frame weighted
    k(1-w), its twin the next baked frame weighted kw, k the density scale (every smoke
    coefficient scales with the weight); a domain with weight 0 is hidden."""
    if not built.domain:
        return
    visible = visible and density_scale > 0.0
    current = bpy.data.objects[built.domain]
    current[SMOKE_WEIGHT] = density_scale * (1.0 - next_weight)
    current.hide_render = not visible
    if built.domain_next:
        twin = bpy.data.objects[built.domain_next]
        twin[SMOKE_WEIGHT] = density_scale * next_weight
        twin.hide_render = not visible or next_weight == 0.0
    elif next_weight != 0.0:
        raise RuntimeError("a fractional frame needs the interpolation twin of the smoke domain")


def render_to(path: str, c2w: Sequence[Sequence[float]], blender_frame: int) -> None:
    """Render one image; write aside and rename so a crash never leaves a partial file."""
    scene = bpy.context.scene
    scene.frame_set(blender_frame)  # always: right after a bake the current frame's state is stale
    scene.camera.matrix_world = Matrix(c2w)
    with atomic_path(Path(path)) as tmp:
        scene.render.filepath = str(tmp)
        bpy.ops.render.render(write_still=True)
