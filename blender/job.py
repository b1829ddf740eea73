"""The worker's job: the typed contract between `generator/` (which writes it) and the Blender
worker (which reads it). Pure Python, no bpy, so the generator can import it.

Written as JSON by `WorkerJob.write`; read back by `WorkerJob.read`, which checks every field's
type against these dataclasses and the value rules in `check`, naming the file and the dotted
field of the first problem. Both sides call `check`, so a job that one side accepts the other
accepts too.
"""
from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from contracts.atomic import write_text
from contracts.dataset_format import MODALITY_PASSES

Vec3 = tuple[float, float, float]

DENOISERS = ("none", "color", "albedo", "albedo_normal")
TEXTURE_KINDS = ("none", "noise", "checker", "brick", "wave", "voronoi", "magic")
SOURCE_KINDS = ("smoke", "fire", "both")
CLEAN_SAMPLE_PASSES = ("clean", "shadowed")
"""The ground-truth images, rendered at the camera's `clean_samples` and never denoised."""
SMOKE_PASSES = ("smoky", "shadowed", "smoke_alpha")
"""The passes that need the smoke domain: those that show the smoke, and `shadowed`, lit through
it. A job that asks for none of them (clean ground truth alone, depth) needs no smoke domain and
so no bake."""


def built_scene_path(blend_path: str) -> Path:
    """The bake stage's description of the saved scene (`blender.scene.BuiltScene`), written
    after the scene, so its presence means the bake finished."""
    return Path(blend_path).with_suffix(".built.json")


class JobError(ValueError):
    """A job file that does not match this contract."""


@dataclass(frozen=True)
class TextureJob:
    kind: str
    scale: float
    color2: Vec3
    detail: float
    mortar_color: Vec3


@dataclass(frozen=True)
class MaterialJob:
    """`thermal_curve`: (texture factor, leaving LWIR radiance) points, piecewise linear."""

    name: str
    base_color: Vec3
    roughness: float
    metallic: float
    texture: TextureJob
    thermal_curve: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class AssetJob:
    """A recipe (built in Blender) or a mesh file already checked and saved as arrays."""

    kind: str
    params: dict[str, Any]
    recipe: str | None = None
    mesh_npz: str | None = None


@dataclass(frozen=True)
class ObjectJob:
    name: str
    asset: AssetJob
    material: str
    location: Vec3
    rotation_deg: Vec3
    scale: Vec3
    params: dict[str, Any]


@dataclass(frozen=True)
class WorldJob:
    sky_color: Vec3
    sky_strength: float
    sun_strength: float
    sun_elevation_deg: float
    sun_azimuth_deg: float
    thermal_sky_radiance: float


@dataclass(frozen=True)
class SimJob:
    fps: int
    resolution: int
    center: Vec3
    size: Vec3
    vorticity: float
    buoyancy_density: float
    buoyancy_heat: float
    wind: Vec3
    dissolve_frames: int
    noise_upres: int
    frame_end: int


@dataclass(frozen=True)
class SourceJob:
    """`heat` is Blender's relative flow temperature."""

    kind: str
    position: Vec3
    radius: float
    rate: float
    heat: float
    velocity: Vec3


@dataclass(frozen=True)
class FireJob:
    """Gas at T = ambient + flame·(flame_k − ambient): `glow_table` rows (flame, r, g, b) are its
    visible emission per metre, `radiance_curve` rows (flame, L_band) its LWIR radiance."""

    ambient_k: float
    flame_k: float
    visible_strength: float
    glow_table: tuple[tuple[float, float, float, float], ...]
    radiance_curve: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class RgbSmokeJob:
    """Per-unit-grid-density coefficients (1/m) of Cycles' Volume Scatter and Absorption."""

    scatter_density: float
    scatter_color: Vec3
    absorb_density: float
    absorb_color: Vec3
    anisotropy: float
    fire: FireJob | None


@dataclass(frozen=True)
class ThermalSmokeJob:
    """LWIR smoke: absorption per unit grid density, and Kirchhoff emission sigma_a * L_band(T):
    T from the flame grid with fire, else the ambient temperature (`ambient_radiance`)."""

    absorption_per_density: float
    ambient_radiance: float
    fire: FireJob | None


@dataclass(frozen=True)
class FrameJob:
    """One image: the smoke is baked frame `blender_frame` blended with the next by `next_weight`;
    `split` (train or test) says which passes render it (`contracts.dataset_format.has_frame`)."""

    stem: str
    blender_frame: int
    next_weight: float
    c2w: tuple[tuple[float, float, float, float], ...]
    split: str


@dataclass(frozen=True)
class ImageSize:
    width: int
    height: int
    fl_x: float


@dataclass(frozen=True)
class CameraJob:
    """`render` is the size of the rendered images (thermal: supersampled), `depth` the sensor's."""

    render: ImageSize
    depth: ImageSize
    samples: int
    clean_samples: int
    denoise: str
    volume_step_rate: float
    frames: tuple[FrameJob, ...]


@dataclass(frozen=True)
class WorkerJob:
    seed: int
    threads: int
    blend_path: str
    cache_dir: str
    raw_dir: str
    summary_path: str
    grids: tuple[str, ...]
    materials: dict[str, MaterialJob]
    objects: tuple[ObjectJob, ...]
    world: WorldJob
    sim: SimJob
    sources: tuple[SourceJob, ...]
    smoke_rgb: RgbSmokeJob
    smoke_thermal: ThermalSmokeJob
    density_scale: float
    cameras: dict[str, CameraJob]
    passes: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def to_data(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def write(self, path: Path) -> None:
        """Checked, then written atomically (the worker may be started on it at any time)."""
        check(self, str(path))
        write_text(path, json.dumps(self.to_data(), indent=1))

    @classmethod
    def read(cls, path: Path) -> "WorkerJob":
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise JobError(f"{path}: not a readable job file ({exc})") from None
        job = decode(cls, data, str(path), "")
        check(job, str(path))
        return job


def _fail(source: str, where: str, message: str) -> JobError:
    return JobError(f"{source}: {where or '(top level)'}: {message}")


def decode(kind: Any, value: Any, source: str, where: str) -> Any:
    """`value` (parsed JSON) as an instance of the annotated type `kind`, or JobError."""
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(kind)
        if value is None and type(None) in options:
            return None
        return decode(next(o for o in options if o is not type(None)), value, source, where)
    if dataclasses.is_dataclass(kind):
        if not isinstance(value, dict):
            raise _fail(source, where, f"must be an object, got {type(value).__name__}")
        hints = typing.get_type_hints(kind)
        names = {f.name for f in dataclasses.fields(kind)}
        unknown = sorted(set(value) - names)
        if unknown:
            raise _fail(source, f"{where}.{unknown[0]}".lstrip("."), "unknown field")
        values = {}
        for f in dataclasses.fields(kind):
            path = f"{where}.{f.name}".lstrip(".")
            if f.name not in value:
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                    raise _fail(source, path, "missing")
                continue
            values[f.name] = decode(hints[f.name], value[f.name], source, path)
        return kind(**values)
    if origin is tuple:
        args = typing.get_args(kind)
        if not isinstance(value, (list, tuple)):
            raise _fail(source, where, f"must be a list, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(decode(args[0], v, source, f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise _fail(source, where, f"must have {len(args)} items, got {len(value)}")
        return tuple(decode(a, v, source, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if origin is dict:
        key_kind, value_kind = typing.get_args(kind)
        if not isinstance(value, dict):
            raise _fail(source, where, f"must be an object, got {type(value).__name__}")
        return {str(k): decode(value_kind, v, source, f"{where}.{k}") for k, v in value.items()}
    if kind is Any:
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _fail(source, where, f"must be a finite number, got {value!r}")
        return float(value)
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(source, where, f"must be an integer, got {value!r}")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise _fail(source, where, f"must be a string, got {value!r}")
        return value
    raise TypeError(f"no decoder for {kind!r}")


def check(job: WorkerJob, source: str) -> None:
    """Value rules beyond types: known kinds and passes, weights in [0, 1), consistent names."""
    def need(ok: bool, where: str, message: str) -> None:
        if not ok:
            raise _fail(source, where, message)

    for name, mat in job.materials.items():
        need(mat.texture.kind in TEXTURE_KINDS, f"materials.{name}.texture.kind", f"unknown kind {mat.texture.kind!r}")
        need(len(mat.thermal_curve) >= 1, f"materials.{name}.thermal_curve", "needs at least one point")
    for i, obj in enumerate(job.objects):
        need(obj.material in job.materials, f"objects[{i}].material", f"unknown material {obj.material!r}")
        need(obj.asset.kind in ("recipe", "file"), f"objects[{i}].asset.kind", f"unknown kind {obj.asset.kind!r}")
        need((obj.asset.recipe is not None) == (obj.asset.kind == "recipe"), f"objects[{i}].asset.recipe",
             "a recipe asset needs a recipe name, and only it")
        need((obj.asset.mesh_npz is not None) == (obj.asset.kind == "file"), f"objects[{i}].asset.mesh_npz",
             "a file asset needs its mesh arrays, and only it")
    for i, src in enumerate(job.sources):
        need(src.kind in SOURCE_KINDS, f"sources[{i}].kind", f"unknown kind {src.kind!r}")
        need(src.radius > 0 and src.rate > 0, f"sources[{i}]", "radius and rate must be positive")
    need(job.sim.fps > 0 and job.sim.resolution >= 8 and job.sim.frame_end >= 1, "sim",
         "fps must be positive, resolution at least 8, frame_end at least 1")
    need(job.threads >= 1, "threads", "must be at least 1")
    need(job.density_scale >= 0.0, "density_scale", "must not be negative")
    for modality, passes in job.passes.items():
        need(modality in MODALITY_PASSES and modality in job.cameras, f"passes.{modality}",
             "unknown modality or no camera for it")
        for name in passes:
            need(name in MODALITY_PASSES[modality], f"passes.{modality}", f"unknown pass {name!r}")
    for modality, cam in job.cameras.items():
        where = f"cameras.{modality}"
        need(cam.denoise in DENOISERS, f"{where}.denoise", f"must be one of {', '.join(DENOISERS)}")
        need(cam.samples >= 1 and cam.clean_samples >= 1 and cam.volume_step_rate > 0, where,
             "samples, clean_samples and volume_step_rate must be positive")
        for size_name, size in (("render", cam.render), ("depth", cam.depth)):
            need(size.width >= 1 and size.height >= 1 and size.fl_x > 0, f"{where}.{size_name}",
                 "width, height and fl_x must be positive")
        for j, frame in enumerate(cam.frames):
            need(0.0 <= frame.next_weight < 1.0, f"{where}.frames[{j}].next_weight", "must lie in [0, 1)")
            need(1 <= frame.blender_frame <= job.sim.frame_end or not job.sources,
                 f"{where}.frames[{j}].blender_frame", f"outside the bake (1..{job.sim.frame_end})")
            need(frame.next_weight == 0.0 or frame.blender_frame < job.sim.frame_end,
                 f"{where}.frames[{j}]", "interpolates past the last baked frame")
            need(len(frame.c2w) == 4, f"{where}.frames[{j}].c2w", "must be a 4x4 matrix")
            need(frame.split in ("train", "test"), f"{where}.frames[{j}].split", "must be 'train' or 'test'")
