"""The scene spec: typed dataclasses parsed and validated from YAML (docs/scene-spec.md)."""
from __future__ import annotations

import copy
import hashlib
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from generator.errors import SpecError
from generator.fields import Fields

TEXTURE_KINDS = ("none", "noise", "checker", "brick", "wave", "voronoi", "magic")
SOURCE_KINDS = ("smoke", "fire", "both")
TRAJECTORY_KINDS = ("orbit", "flyover")
PARTICLE_KINDS = ("organic_smoke", "soot")
MODALITIES = ("rgb", "thermal")
DENOISERS = ("none", "color", "albedo", "albedo_normal")
PASSES = ("smoky", "clean", "depth", "smoke_alpha")


@dataclass(frozen=True)
class TextureSpec:
    """A procedural texture mixing `base_color` and `color2`; also modulates temperature."""

    kind: str = "none"
    scale: float = 5.0
    color2: tuple[float, float, float] = (0.2, 0.2, 0.2)
    detail: float = 4.0
    mortar_color: tuple[float, float, float] = (0.75, 0.73, 0.7)


@dataclass(frozen=True)
class MaterialSpec:
    name: str
    base_color: tuple[float, float, float]
    roughness: float = 0.6
    metallic: float = 0.0
    texture: TextureSpec = TextureSpec()
    temperature_k: float = 293.15
    temperature_variation_k: float = 0.0
    emissivity: float = 0.95


@dataclass(frozen=True)
class ObjectSpec:
    """`material` None means the asset's default material from the manifest (resolved by
    `generator.job.resolve_asset_materials` before anything is rendered)."""

    name: str
    asset: str
    material: str | None = None
    location: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SourceSpec:
    """A Mantaflow inflow: `rate` is the flow's density amount, fire adds fuel and heat."""

    kind: str
    position: tuple[float, float, float]
    radius: float = 0.2
    rate: float = 1.0
    temperature_k: float = 320.0
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class SimSpec:
    fps: int = 12
    resolution: int = 24
    center: tuple[float, float, float] = (0.0, 0.0, 1.0)
    size: tuple[float, float, float] = (2.0, 2.0, 2.0)
    vorticity: float = 0.2
    buoyancy_density: float = 0.0
    buoyancy_heat: float = 1.0
    wind: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dissolve_s: float = 0.0
    noise_upres: int = 0
    warmup_s: float = 1.0
    static: bool = False


@dataclass(frozen=True)
class SmokeSpec:
    """`density` is the paper's per-scene smoke density (0.2-1.0); `extinction_per_m` maps it
    to a visible extinction coefficient per unit Mantaflow grid density."""

    density: float = 0.7
    extinction_per_m: float = 8.0
    particles: str = "organic_smoke"
    mask_threshold: float = 0.02


@dataclass(frozen=True)
class LightSpec:
    sun_strength: float = 3.0
    sun_elevation_deg: float = 50.0
    sun_azimuth_deg: float = 30.0
    sky_color: tuple[float, float, float] = (0.55, 0.65, 0.85)
    sky_strength: float = 0.8
    sky_temperature_k: float = 250.0
    ambient_temperature_k: float = 293.15


@dataclass(frozen=True)
class TrajectorySpec:
    kind: str = "orbit"
    center: tuple[float, float, float] = (0.0, 0.0, 0.5)
    radius: float = 4.0
    height: float = 1.5
    start_deg: float = 0.0
    sweep_deg: float = 90.0
    start: tuple[float, float, float] = (-4.0, -4.0, 6.0)
    end: tuple[float, float, float] = (4.0, -4.0, 6.0)
    look_from: tuple[float, float, float] = (-1.0, 1.0, 0.0)
    look_to: tuple[float, float, float] = (1.0, 1.0, 0.0)


@dataclass(frozen=True)
class CameraSpec:
    """`denoise` runs OpenImageDenoise on the smoky image only (the image a real camera gives);
    ground-truth passes are never denoised. `volume_step_rate` scales Cycles' volume ray-march
    step (larger is faster and coarser)."""

    width: int
    height: int
    fov_deg: float
    fps: float
    samples: int
    time_offset_s: float = 0.0
    denoise: str = "albedo_normal"
    volume_step_rate: float = 1.0


@dataclass(frozen=True)
class ThermalCameraSpec(CameraSpec):
    baseline_m: tuple[float, float, float] = (0.06, 0.0, 0.0)
    supersample: int = 2
    sensor: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class RigSpec:
    trajectory: TrajectorySpec
    rgb: CameraSpec
    thermal: ThermalCameraSpec


@dataclass(frozen=True)
class SceneSpec:
    name: str
    seed: int
    frames: int
    test_every: int
    sim: SimSpec
    smoke: SmokeSpec
    sources: tuple[SourceSpec, ...]
    objects: tuple[ObjectSpec, ...]
    materials: dict[str, MaterialSpec]
    lights: LightSpec
    rig: RigSpec
    passes: dict[str, tuple[str, ...]]

    @property
    def has_smoke(self) -> bool:
        return bool(self.sources)

    @property
    def has_fire(self) -> bool:
        return any(s.kind in ("fire", "both") for s in self.sources)

    def to_dict(self) -> dict[str, Any]:
        """The spec as plain YAML-ready data that `parse_spec` reads back to an equal spec
        (a material's name is its key, so it is not repeated inside the entry)."""
        d = _to_yaml_ready(asdict(self))
        for entry in d["materials"].values():
            entry.pop("name")
        for source in d["sources"]:
            source["type"] = source.pop("kind")
        d["passes"] = [f"{m}.{p}" for m, names in self.passes.items() for p in names]
        return d

    def sha256(self) -> str:
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def _to_yaml_ready(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _to_yaml_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_to_yaml_ready(v) for v in value]
    return value


def parse_texture(f: Fields) -> TextureSpec:
    d = TextureSpec()
    spec = TextureSpec(
        kind=f.string("kind", d.kind, TEXTURE_KINDS),
        scale=f.number("scale", d.scale, minimum=0.0, exclusive_minimum=True),
        color2=f.vector("color2", 3, d.color2, 0.0, 1.0),
        detail=f.number("detail", d.detail, minimum=0.0, maximum=16.0),
        mortar_color=f.vector("mortar_color", 3, d.mortar_color, 0.0, 1.0),
    )
    f.finish()
    return spec


def _material(name: str, f: Fields) -> MaterialSpec:
    d = MaterialSpec(name=name, base_color=(0.5, 0.5, 0.5))
    spec = MaterialSpec(
        name=name,
        base_color=f.vector("base_color", 3, d.base_color, 0.0, 1.0),
        roughness=f.number("roughness", d.roughness, 0.0, 1.0),
        metallic=f.number("metallic", d.metallic, 0.0, 1.0),
        texture=parse_texture(f.sub("texture")),
        temperature_k=f.number("temperature_k", d.temperature_k, minimum=0.0, maximum=5000.0,
                               exclusive_minimum=True),
        temperature_variation_k=f.number("temperature_variation_k", d.temperature_variation_k, 0.0, 500.0),
        emissivity=f.number("emissivity", d.emissivity, 0.0, 1.0),
    )
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
    spec = ObjectSpec(
        name=f.string("name", f"{asset}_{i}"),
        asset=asset,
        material=material,
        location=f.vector("location", 3, (0.0, 0.0, 0.0)),
        rotation_deg=f.vector("rotation_deg", 3, (0.0, 0.0, 0.0)),
        scale=f.vector("scale", 3, (1.0, 1.0, 1.0), minimum=1e-6),
        params=f.mapping("params"),
    )
    f.finish()
    return spec


def _source(f: Fields) -> SourceSpec:
    d = SourceSpec(kind="smoke", position=(0.0, 0.0, 0.0))
    spec = SourceSpec(
        kind=f.string("type", d.kind, SOURCE_KINDS),
        position=f.vector("position", 3),
        radius=f.number("radius", d.radius, minimum=0.0, exclusive_minimum=True),
        rate=f.number("rate", d.rate, minimum=0.0, maximum=10.0, exclusive_minimum=True),
        temperature_k=f.number("temperature_k", d.temperature_k, minimum=0.0, maximum=5000.0,
                               exclusive_minimum=True),
        velocity=f.vector("velocity", 3, d.velocity),
    )
    f.finish()
    return spec


def _sim(f: Fields) -> SimSpec:
    d = SimSpec()
    spec = SimSpec(
        fps=f.integer("fps", d.fps, 1, 240),
        resolution=f.integer("resolution", d.resolution, 8, 1024),
        center=f.vector("center", 3, d.center),
        size=f.vector("size", 3, d.size, minimum=1e-3),
        vorticity=f.number("vorticity", d.vorticity, 0.0, 10.0),
        buoyancy_density=f.number("buoyancy_density", d.buoyancy_density, -10.0, 10.0),
        buoyancy_heat=f.number("buoyancy_heat", d.buoyancy_heat, -10.0, 10.0),
        wind=f.vector("wind", 3, d.wind),
        dissolve_s=f.number("dissolve_s", d.dissolve_s, 0.0),
        noise_upres=f.integer("noise_upres", d.noise_upres, 0, 4),
        warmup_s=f.number("warmup_s", d.warmup_s, 0.0, 60.0),
        static=f.boolean("static", d.static),
    )
    f.finish()
    return spec


def _smoke(f: Fields) -> SmokeSpec:
    d = SmokeSpec()
    spec = SmokeSpec(
        density=f.number("density", d.density, 0.0, 100.0),
        extinction_per_m=f.number("extinction_per_m", d.extinction_per_m, 0.0, 1e4),
        particles=f.string("particles", d.particles, PARTICLE_KINDS),
        mask_threshold=f.number("mask_threshold", d.mask_threshold, 0.0, 1.0, exclusive_minimum=True),
    )
    f.finish()
    return spec


def _lights(f: Fields) -> LightSpec:
    d = LightSpec()
    spec = LightSpec(
        sun_strength=f.number("sun_strength", d.sun_strength, 0.0),
        sun_elevation_deg=f.number("sun_elevation_deg", d.sun_elevation_deg, -90.0, 90.0),
        sun_azimuth_deg=f.number("sun_azimuth_deg", d.sun_azimuth_deg),
        sky_color=f.vector("sky_color", 3, d.sky_color, 0.0, 1.0),
        sky_strength=f.number("sky_strength", d.sky_strength, 0.0),
        sky_temperature_k=f.number("sky_temperature_k", d.sky_temperature_k, 0.0, 5000.0, exclusive_minimum=True),
        ambient_temperature_k=f.number("ambient_temperature_k", d.ambient_temperature_k, 0.0, 5000.0,
                                       exclusive_minimum=True),
    )
    f.finish()
    return spec


def _trajectory(f: Fields) -> TrajectorySpec:
    d = TrajectorySpec()
    spec = TrajectorySpec(
        kind=f.string("kind", d.kind, TRAJECTORY_KINDS),
        center=f.vector("center", 3, d.center),
        radius=f.number("radius", d.radius, minimum=0.0, exclusive_minimum=True),
        height=f.number("height", d.height),
        start_deg=f.number("start_deg", d.start_deg),
        sweep_deg=f.number("sweep_deg", d.sweep_deg, -720.0, 720.0),
        start=f.vector("start", 3, d.start),
        end=f.vector("end", 3, d.end),
        look_from=f.vector("look_from", 3, d.look_from),
        look_to=f.vector("look_to", 3, d.look_to),
    )
    f.finish()
    return spec


def _camera_fields(f: Fields, defaults: CameraSpec) -> dict[str, Any]:
    return dict(
        width=f.integer("width", defaults.width, 1, 16384),
        height=f.integer("height", defaults.height, 1, 16384),
        fov_deg=f.number("fov_deg", defaults.fov_deg, 1.0, 170.0),
        fps=f.number("fps", defaults.fps, minimum=0.0, maximum=1000.0, exclusive_minimum=True),
        samples=f.integer("samples", defaults.samples, 1, 65536),
        time_offset_s=f.number("time_offset_s", defaults.time_offset_s, 0.0, 10.0),
        denoise=f.string("denoise", defaults.denoise, DENOISERS),
        volume_step_rate=f.number("volume_step_rate", defaults.volume_step_rate, 0.01, 100.0),
    )


def _rig(f: Fields) -> RigSpec:
    rgb_f = f.sub("rgb")
    rgb = CameraSpec(**_camera_fields(rgb_f, CameraSpec(64, 48, 55.0, 12.0, 16)))
    rgb_f.finish()
    th_f = f.sub("thermal")
    thermal = ThermalCameraSpec(
        **_camera_fields(th_f, CameraSpec(32, 24, 45.0, 9.0, 8, 0.03)),
        baseline_m=th_f.vector("baseline_m", 3, (0.06, 0.0, 0.0)),
        supersample=th_f.integer("supersample", 2, 1, 8),
        sensor=th_f.mapping("sensor"),
    )
    th_f.finish()
    spec = RigSpec(trajectory=_trajectory(f.sub("trajectory")), rgb=rgb, thermal=thermal)
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
        names = [pass_name] if pass_name else list(PASSES)
        for name in names:
            if name not in PASSES:
                raise SpecError(source, field_name, f"unknown pass in {item!r}; use {', '.join(PASSES)}")
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
    spec = SceneSpec(
        name=f.string("name"),
        seed=f.integer("seed", 0, 0, 2**31 - 1),
        frames=f.integer("frames", 8, 1, 100000),
        test_every=f.integer("test_every", 4, 2, 1000),
        sim=_sim(f.sub("sim")),
        smoke=_smoke(f.sub("smoke")),
        sources=tuple(_source(sf) for sf in f.sub_list("sources")),
        objects=objects,
        materials=materials,
        lights=_lights(f.sub("lights")),
        rig=_rig(f.sub("rig")),
        passes=parse_passes(passes_raw, str(source)),
    )
    f.finish()
    return spec


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
    return out
