"""The scene spec: typed dataclasses parsed and validated from YAML (docs/scene-spec.md)."""
from __future__ import annotations

import copy
import hashlib
import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import yaml

from blender.job import CLEAN_SAMPLE_PASSES
from contracts.dataset_format import MODALITY_PASSES, has_frame
from generator.errors import SpecError
from generator.fields import REQUIRED, Fields, read_fields, spec_field

T = TypeVar("T")

TEXTURE_KINDS = ("none", "noise", "checker", "brick", "wave", "voronoi", "magic")
SOURCE_KINDS = ("smoke", "fire", "both")
TRAJECTORY_KINDS = ("orbit", "flyover")
PARTICLE_KINDS = ("organic_smoke", "soot")
MODALITIES = ("rgb", "thermal")
DENOISERS = ("none", "color", "albedo", "albedo_normal")
PASSES = ("smoky", "clean", "shadowed", "depth", "smoke_alpha")
"""Every pass name, in the order a selection lists them; each camera has its own
(`contracts.dataset_format.MODALITY_PASSES`)."""

CLEAN_SAMPLES_RGB = 256
CLEAN_SAMPLES_THERMAL = 32
"""Default samples of the smoke-free passes: the fewest that keep the clean frames 45 dB or more
from a render with 4x the samples on the demo and a standard scene (docs/generator.md,
`benchmarks/clean_convergence.py`)."""

BYTES_PER_RENDER_PIXEL = 64
"""What one pixel of one render holds at once: Cycles' float RGBA film and the denoiser's albedo
and normal guides (16 bytes each), and the float image written and read back (16)."""
MAX_RENDER_BYTES = 16 * 2**30
"""One frame's render must fit in 16 GiB: a 16384 × 16384 RGB frame, the largest the camera
fields allow, and no more."""
MAX_PIXEL_SAMPLES = 10**12
"""Cycles samples over every pixel of every rendered pass and frame."""
PIXEL_SAMPLES_PER_S = 5e4
"""The render rate measured on a 2-core CPU (docs/generator.md: 64×48 at 128 samples, 7.2 s a
frame), for the time estimate in the refusal."""


@dataclass(frozen=True)
class TextureSpec:
    """A procedural texture mixing `base_color` and `color2`; also modulates temperature."""

    kind: str = spec_field("none", choices=TEXTURE_KINDS)
    scale: float = spec_field(5.0, minimum=0.0, exclusive_minimum=True)
    color2: tuple[float, float, float] = spec_field((0.2, 0.2, 0.2), minimum=0.0, maximum=1.0)
    detail: float = spec_field(4.0, minimum=0.0, maximum=16.0)
    mortar_color: tuple[float, float, float] = spec_field((0.75, 0.73, 0.7), minimum=0.0, maximum=1.0)


@dataclass(frozen=True)
class MaterialSpec:
    name: str
    base_color: tuple[float, float, float] = spec_field((0.5, 0.5, 0.5), minimum=0.0, maximum=1.0)
    roughness: float = spec_field(0.6, minimum=0.0, maximum=1.0)
    metallic: float = spec_field(0.0, minimum=0.0, maximum=1.0)
    texture: TextureSpec = spec_field(TextureSpec())
    temperature_k: float = spec_field(293.15, minimum=0.0, maximum=5000.0, exclusive_minimum=True)
    temperature_variation_k: float = spec_field(0.0, minimum=0.0, maximum=500.0)
    emissivity: float = spec_field(0.95, minimum=0.0, maximum=1.0)


@dataclass(frozen=True)
class ObjectSpec:
    """`material` None means the asset's default material from the manifest (resolved by
    `generator.job.resolve_asset_materials` before anything is rendered)."""

    name: str
    asset: str
    material: str | None = None
    location: tuple[float, float, float] = spec_field((0.0, 0.0, 0.0))
    rotation_deg: tuple[float, float, float] = spec_field((0.0, 0.0, 0.0))
    scale: tuple[float, float, float] = spec_field((1.0, 1.0, 1.0), minimum=1e-6)
    params: dict[str, Any] = spec_field({})


@dataclass(frozen=True)
class SourceSpec:
    """A Mantaflow inflow: `rate` is the flow's density amount, fire adds fuel and heat."""

    position: tuple[float, float, float] = spec_field(REQUIRED)
    kind: str = spec_field("smoke", choices=SOURCE_KINDS, key="type")
    radius: float = spec_field(0.2, minimum=0.0, exclusive_minimum=True)
    rate: float = spec_field(1.0, minimum=0.0, maximum=10.0, exclusive_minimum=True)
    temperature_k: float = spec_field(320.0, minimum=0.0, maximum=5000.0, exclusive_minimum=True)
    velocity: tuple[float, float, float] = spec_field((0.0, 0.0, 0.0))


@dataclass(frozen=True)
class SimSpec:
    fps: int = spec_field(12, minimum=1, maximum=240)
    resolution: int = spec_field(24, minimum=8, maximum=1024)
    center: tuple[float, float, float] = spec_field((0.0, 0.0, 1.0))
    size: tuple[float, float, float] = spec_field((2.0, 2.0, 2.0), minimum=1e-3)
    vorticity: float = spec_field(0.2, minimum=0.0, maximum=10.0)
    buoyancy_density: float = spec_field(0.0, minimum=-10.0, maximum=10.0)
    buoyancy_heat: float = spec_field(1.0, minimum=-10.0, maximum=10.0)
    wind: tuple[float, float, float] = spec_field((0.0, 0.0, 0.0))
    dissolve_s: float = spec_field(0.0, minimum=0.0)
    noise_upres: int = spec_field(0, minimum=0, maximum=4)
    warmup_s: float = spec_field(1.0, minimum=0.0, maximum=60.0)
    static: bool = spec_field(False)


@dataclass(frozen=True)
class SmokeSpec:
    """`density` is the paper's per-scene smoke density (0.2-1.0); `extinction_per_m` maps it
    to a visible extinction coefficient per unit Mantaflow grid density. `density_scale` k
    multiplies every smoke coefficient at render time, the same bake rendered k times denser:
    opacity becomes 1 - (1 - alpha)^k, and k = 0 is the smoke-free scene (the density axis).
    `optical_depth`, when set, is the mean RGB optical depth the smoke must have over the RGB
    views at k = 1: the generator calibrates every coefficient to it after the bake
    (generator.optical_depth)."""

    density: float = spec_field(0.7, minimum=0.0, maximum=100.0)
    density_scale: float = spec_field(1.0, minimum=0.0, maximum=1000.0)
    extinction_per_m: float = spec_field(8.0, minimum=0.0, maximum=1e4)
    particles: str = spec_field("organic_smoke", choices=PARTICLE_KINDS)
    mask_threshold: float = spec_field(0.02, minimum=0.0, maximum=1.0, exclusive_minimum=True)
    optical_depth: float | None = spec_field(None, minimum=0.0, maximum=50.0, exclusive_minimum=True)


@dataclass(frozen=True)
class LightSpec:
    sun_strength: float = spec_field(3.0, minimum=0.0)
    sun_elevation_deg: float = spec_field(50.0, minimum=-90.0, maximum=90.0)
    sun_azimuth_deg: float = spec_field(30.0)
    sky_color: tuple[float, float, float] = spec_field((0.55, 0.65, 0.85), minimum=0.0, maximum=1.0)
    sky_strength: float = spec_field(0.8, minimum=0.0)
    sky_temperature_k: float = spec_field(250.0, minimum=0.0, maximum=5000.0, exclusive_minimum=True)
    ambient_temperature_k: float = spec_field(293.15, minimum=0.0, maximum=5000.0, exclusive_minimum=True)


@dataclass(frozen=True)
class TrajectorySpec:
    kind: str = spec_field("orbit", choices=TRAJECTORY_KINDS)
    center: tuple[float, float, float] = spec_field((0.0, 0.0, 0.5))
    radius: float = spec_field(4.0, minimum=0.0, exclusive_minimum=True)
    height: float = spec_field(1.5)
    start_deg: float = spec_field(0.0)
    sweep_deg: float = spec_field(90.0, minimum=-720.0, maximum=720.0)
    start: tuple[float, float, float] = spec_field((-4.0, -4.0, 6.0))
    end: tuple[float, float, float] = spec_field((4.0, -4.0, 6.0))
    look_from: tuple[float, float, float] = spec_field((-1.0, 1.0, 0.0))
    look_to: tuple[float, float, float] = spec_field((1.0, 1.0, 0.0))


@dataclass(frozen=True)
class CameraSpec:
    """`denoise` runs OpenImageDenoise on the smoky image only (the image a real camera gives);
    ground-truth passes are never denoised. `clean_samples` are the samples of the smoke-free
    passes: ground truth, converged rather than denoised (docs/generator.md). `volume_step_rate`
    scales Cycles' volume ray-march step (larger is faster and coarser). Defaults differ per
    camera: RGB_CAMERA, THERMAL_CAMERA."""

    width: int = spec_field(REQUIRED, minimum=1, maximum=16384)
    height: int = spec_field(REQUIRED, minimum=1, maximum=16384)
    fov_deg: float = spec_field(REQUIRED, minimum=1.0, maximum=170.0)
    fps: float = spec_field(REQUIRED, minimum=0.0, maximum=1000.0, exclusive_minimum=True)
    samples: int = spec_field(REQUIRED, minimum=1, maximum=65536)
    clean_samples: int = spec_field(REQUIRED, minimum=1, maximum=65536)
    time_offset_s: float = spec_field(0.0, minimum=0.0, maximum=10.0)
    denoise: str = spec_field("albedo_normal", choices=DENOISERS)
    volume_step_rate: float = spec_field(1.0, minimum=0.01, maximum=100.0)


@dataclass(frozen=True)
class ThermalCameraSpec(CameraSpec):
    baseline_m: tuple[float, float, float] = spec_field((0.06, 0.0, 0.0))
    supersample: int = spec_field(2, minimum=1, maximum=8)
    sensor: dict[str, Any] = spec_field({})


RGB_CAMERA = CameraSpec(width=64, height=48, fov_deg=55.0, fps=12.0, samples=16, clean_samples=CLEAN_SAMPLES_RGB)
THERMAL_CAMERA = ThermalCameraSpec(width=32, height=24, fov_deg=45.0, fps=9.0, samples=8,
                                   clean_samples=CLEAN_SAMPLES_THERMAL, time_offset_s=0.03)


@dataclass(frozen=True)
class RigSpec:
    trajectory: TrajectorySpec
    rgb: CameraSpec
    thermal: ThermalCameraSpec


@dataclass(frozen=True)
class SceneSpec:
    """The whole scene. Fields with metadata are read generically (`read_fields`); `sources`,
    `objects`, `materials`, `rig` and `passes` have their own readers in `parse_spec`."""

    name: str = spec_field(REQUIRED)
    seed: int = spec_field(0, minimum=0, maximum=2**31 - 1)
    frames: int = spec_field(8, minimum=1, maximum=100000)
    test_every: int = spec_field(4, minimum=2, maximum=1000)
    sim: SimSpec = spec_field(SimSpec())
    smoke: SmokeSpec = spec_field(SmokeSpec())
    sources: tuple[SourceSpec, ...] = ()
    objects: tuple[ObjectSpec, ...] = ()
    materials: dict[str, MaterialSpec] = field(default_factory=dict)
    lights: LightSpec = spec_field(LightSpec())
    rig: RigSpec = field(default_factory=lambda: RigSpec(TrajectorySpec(), RGB_CAMERA, THERMAL_CAMERA))
    passes: dict[str, tuple[str, ...]] = field(default_factory=dict)

    @property
    def has_smoke(self) -> bool:
        return bool(self.sources)

    @property
    def has_fire(self) -> bool:
        return any(s.kind in ("fire", "both") for s in self.sources)

    def test_frames(self) -> set[int]:
        """The RGB frames held out for scoring: every ``test_every``-th, the first half a step in."""
        return set(range(self.test_every // 2, self.frames, self.test_every)) if self.frames > 1 else set()

    def to_dict(self) -> dict[str, Any]:
        """The spec as plain YAML-ready data that `parse_spec` reads back to an equal spec
        (a material's name is its key, so it is not repeated inside the entry)."""
        d = _to_yaml_ready(asdict(self))
        for entry in d["materials"].values():
            entry.pop("name")
        for source in d["sources"]:
            source["type"] = source.pop("kind")
        d["passes"] = [f"{m}.{p}" for m, names in self.passes.items() for p in names]
        if d["smoke"]["optical_depth"] is None:  # unset: absent, so older specs keep their digest
            del d["smoke"]["optical_depth"]
        return d

    def to_yaml(self) -> str:
        """The spec as YAML in its fields' order (the bytes a dataset's scene.yaml holds)."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    def sha256(self) -> str:
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def _to_yaml_ready(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _to_yaml_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_to_yaml_ready(v) for v in value]
    return value


def parse_section(cls: type[T], f: Fields, defaults: T | None = None, **given: Any) -> T:
    """A spec dataclass read from `f` by its fields' metadata (docs/scene-spec.md); fields
    passed in `given` are set by the caller; unknown keys are errors."""
    spec = cls(**read_fields(cls, f, defaults, skip=tuple(given), nested=parse_section), **given)
    f.finish()
    return spec


def parse_texture(f: Fields) -> TextureSpec:
    return parse_section(TextureSpec, f)


def _material(name: str, f: Fields) -> MaterialSpec:
    spec = MaterialSpec(name=name, **read_fields(MaterialSpec, f, skip=("name",), nested=parse_section))
    if spec.temperature_k - spec.temperature_variation_k / 2 <= 0:
        raise f.error("temperature_variation_k", "would take the temperature to 0 K or below")
    f.finish()
    return spec


def _object(i: int, f: Fields, materials: dict[str, MaterialSpec]) -> ObjectSpec:
    asset = f.string("asset")
    material = f.raw("material", None)
    if material is not None:
        material = f.string("material")
    if material is not None and material not in materials:
        raise f.error("material", f"unknown material {material!r}; defined: {', '.join(sorted(materials)) or 'none'}")
    scale_raw = f.data.get("scale", 1.0)
    if isinstance(scale_raw, (int, float)) and not isinstance(scale_raw, bool):
        f.data = {**f.data, "scale": [scale_raw] * 3}
    return parse_section(ObjectSpec, f, name=f.string("name", f"{asset}_{i}"), asset=asset, material=material)


def _rig(f: Fields) -> RigSpec:
    spec = RigSpec(trajectory=parse_section(TrajectorySpec, f.sub("trajectory")),
                   rgb=parse_section(CameraSpec, f.sub("rgb"), RGB_CAMERA),
                   thermal=parse_section(ThermalCameraSpec, f.sub("thermal"), THERMAL_CAMERA))
    f.finish()
    return spec


def parse_passes(value: Any, source: str, field_name: str = "passes") -> dict[str, tuple[str, ...]]:
    """`rgb.smoky,thermal` style (string or list) to {modality: passes}; modality alone = all."""
    items = value.split(",") if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not items:
        raise SpecError(source, field_name, f"must list MODALITY or MODALITY.PASS items, got {value!r}")
    chosen: dict[str, list[str]] = {}
    for raw in items:
        item = str(raw).strip()
        modality, _, pass_name = item.partition(".")
        if modality not in MODALITIES:
            raise SpecError(source, field_name, f"unknown modality in {item!r}; use {', '.join(MODALITIES)}")
        names = [pass_name] if pass_name else list(MODALITY_PASSES[modality])
        for name in names:
            if name not in MODALITY_PASSES[modality]:
                raise SpecError(source, field_name, f"unknown pass in {item!r}; {modality} has "
                                f"{', '.join(MODALITY_PASSES[modality])}")
            if name not in chosen.setdefault(modality, []):
                chosen[modality].append(name)
    return {m: tuple(p for p in PASSES if p in chosen[m]) for m in MODALITIES if m in chosen}


def parse_spec(data: Any, source: str | Path) -> SceneSpec:
    """Validate a spec mapping; every problem raises SpecError naming `source` and the field."""
    f = Fields(copy.deepcopy(data), str(source))
    materials = {name: _material(name, mf) for name, mf in f.sub_map("materials").items()}
    objects = tuple(_object(i, of, materials) for i, of in enumerate(f.sub_list("objects")))
    names = [o.name for o in objects]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate:
        raise f.error("objects", f"object name {duplicate!r} is used twice")
    passes_raw = f.raw("passes", ["rgb", "thermal"])
    spec = parse_section(SceneSpec, f, sources=tuple(parse_section(SourceSpec, sf) for sf in f.sub_list("sources")),
                         objects=objects, materials=materials, rig=_rig(f.sub("rig")),
                         passes=parse_passes(passes_raw, str(source)))
    check_render_budget(spec, str(source), {"rgb": "rig.rgb", "thermal": "rig.thermal"})
    return spec


def check_render_budget(spec: SceneSpec, source: str, fields: dict[str, str]) -> None:
    """Refuse, before any work, renders that cannot fit in memory or finish: one frame of either
    camera (the thermal one at its supersampled size) within ``MAX_RENDER_BYTES``, and every
    pass of every frame within ``MAX_PIXEL_SAMPLES`` (docs/scene-spec.md "Size limits").
    ``fields`` names each camera's size field as the user gave it."""
    rgb, thermal = spec.rig.rgb, spec.rig.thermal
    duration = (spec.frames - 1) / rgb.fps if spec.frames > 1 else 0.0
    thermal_frames = 1 + max(0, math.floor((duration - thermal.time_offset_s) * thermal.fps + 1e-9))
    cameras = {"rgb": (rgb.width, rgb.height, rgb.samples, spec.frames, 1),
               "thermal": (thermal.width, thermal.height, thermal.samples, thermal_frames, thermal.supersample)}
    clean_samples = {"rgb": rgb.clean_samples, "thermal": thermal.clean_samples}
    tests = len(spec.test_frames())
    work: dict[str, float] = {}
    for modality, (width, height, samples, frames, supersample) in cameras.items():
        pixels = width * height * supersample ** 2
        size = f"{width}x{height}" + (f" (x{supersample} supersampled)" if supersample > 1 else "")
        need = pixels * BYTES_PER_RENDER_PIXEL
        if need > MAX_RENDER_BYTES:
            raise SpecError(source, fields[modality],
                            f"{size} needs about {need / 2**30:,.0f} GiB to render one frame ({BYTES_PER_RENDER_PIXEL} "
                            f"bytes per pixel); the limit is {MAX_RENDER_BYTES // 2**30} GiB")
        work[modality] = float(pixels) * sum(
            (clean_samples[modality] if p in CLEAN_SAMPLE_PASSES else samples)
            * (frames if has_frame(modality, p, "train") else tests)  # a test-view pass renders those alone
            for p in spec.passes.get(modality, ()))
    total = sum(work.values())
    if total > MAX_PIXEL_SAMPLES:
        largest = max(work, key=lambda m: work[m])
        width, height, samples, frames, _ = cameras[largest]
        days = total / PIXEL_SAMPLES_PER_S / 86400
        raise SpecError(source, fields[largest],
                        f"{total:.2g} pixel-samples in all ({frames} {largest} frames of {width}x{height} at {samples} "
                        f"samples, {clean_samples[largest]} for clean and shadowed, {len(spec.passes[largest])} "
                        f"passes), about {days:,.0f} days at {PIXEL_SAMPLES_PER_S:.0e} pixel-samples/s on 2 CPU cores; "
                        f"the limit is {MAX_PIXEL_SAMPLES:.0e}")


def load_spec_file(path: Path) -> SceneSpec:
    try:
        text = path.read_text()
    except OSError as exc:
        raise SpecError(path, "", f"cannot read: {exc.strerror or exc}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else "somewhere"
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise SpecError(path, "", f"malformed YAML at {where}: {problem}") from None
    return parse_spec(data, path)


def _field_maximum(cls: type, name: str) -> float:
    return cls.__dataclass_fields__[name].metadata["maximum"]


@dataclass(frozen=True)
class Overrides:
    """Command-line knobs that replace spec values (None = keep the spec's)."""

    frames: int | None = None
    resolution: tuple[int, int] | None = None
    thermal_resolution: tuple[int, int] | None = None
    samples: int | None = None
    sim_resolution: int | None = None
    seed: int | None = None
    passes: str | None = None
    density_scale: float | None = None


def apply_overrides(spec: SceneSpec, o: Overrides, source: str = "command line") -> SceneSpec:
    def positive(name: str, value: int) -> int:
        if value <= 0:
            raise SpecError(source, f"--{name.replace('_', '-')}", f"must be positive, got {value}")
        return value

    rgb, thermal, sim = spec.rig.rgb, spec.rig.thermal, spec.sim
    if o.resolution is not None:
        rgb = replace(rgb, width=positive("resolution", o.resolution[0]), height=positive("resolution", o.resolution[1]))
    if o.thermal_resolution is not None:
        w, h = o.thermal_resolution
        thermal = replace(thermal, width=positive("thermal_resolution", w), height=positive("thermal_resolution", h))
    if o.samples is not None:
        rgb = replace(rgb, samples=positive("samples", o.samples))
        thermal = replace(thermal, samples=max(1, min(thermal.samples, o.samples)))
    if o.sim_resolution is not None:
        if o.sim_resolution < 8:
            raise SpecError(source, "--sim-resolution", f"must be at least 8, got {o.sim_resolution}")
        sim = replace(sim, resolution=o.sim_resolution)
    out = replace(spec, rig=replace(spec.rig, rgb=rgb, thermal=thermal), sim=sim)
    if o.frames is not None:
        out = replace(out, frames=positive("frames", o.frames))
    if o.seed is not None:
        if o.seed < 0:
            raise SpecError(source, "--seed", f"must be non-negative, got {o.seed}")
        out = replace(out, seed=o.seed)
    if o.passes is not None:
        out = replace(out, passes=parse_passes(o.passes, source, "--passes"))
    if o.density_scale is not None:
        limit = _field_maximum(SmokeSpec, "density_scale")
        if not (math.isfinite(o.density_scale) and 0.0 <= o.density_scale <= limit):
            raise SpecError(source, "--density-scale", f"must be a finite number in [0, {limit:g}], "
                            f"got {o.density_scale!r}")
        out = replace(out, smoke=replace(out.smoke, density_scale=o.density_scale))
    check_render_budget(out, source, {"rgb": "--resolution" if o.resolution else "rig.rgb",
                                      "thermal": "--thermal-resolution" if o.thermal_resolution else "rig.thermal"})
    return out
