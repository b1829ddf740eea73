"""Turns a validated spec into the worker's job (`blender.job.WorkerJob`): all physics numbers
are computed here, so the Blender side only wires nodes and renders."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from contracts.atomic import atomic_path
from contracts.dataset_format import SMOKE_ONLY_PASSES
from blender.job import (SMOKE_PASSES, AssetJob, CameraJob, FireJob, FrameJob, ImageSize, MaterialJob, ObjectJob,
                        RgbSmokeJob, SimJob, SourceJob, TextureJob, ThermalSmokeJob, WorkerJob, WorldJob)
from generator.assets import Manifest, MeshArrays, load_mesh
from generator.optics.blackbody import glow_table
from generator.optics.mie import ORGANIC_SMOKE, SOOT, SmokeOptics, smoke_optics
from generator.optics.planck import band_radiance
from generator.rig import (FrameSample, Intrinsics, Timeline, intrinsics, last_baked_frame, rgb_frames,
                           thermal_frames, timeline)
from generator.spec import CameraSpec, MaterialSpec, SceneSpec

POPULATIONS = {"organic_smoke": ORGANIC_SMOKE, "soot": SOOT}
FIRE_VISIBLE_STRENGTH = 8.0  # scene-linear RGB emission per metre of gas at the flame temperature
THERMAL_CURVE_POINTS = 17
GLOW_TABLE_POINTS = 65  # luminance rises ~e^0.25 per table step near 1300 K: linear lookup within ~1%


@dataclass(frozen=True)
class Plan:
    """Everything the pipeline needs besides the job: frames, intrinsics, optics."""

    timeline: Timeline
    frames: dict[str, list[FrameSample]]
    intrinsics: dict[str, Intrinsics]
    optics: SmokeOptics
    render_passes: dict[str, tuple[str, ...]]

    @property
    def last_frame(self) -> int:
        """The bake must reach the last frame any camera's instant interpolates from."""
        return max(last_baked_frame(f) for f in self.frames.values() if f)


def without_absent_passes(spec: SceneSpec) -> SceneSpec:
    """A smoke-free scene has no smoke opacity and no smoke shadow to render: drop those passes."""
    if spec.has_smoke:
        return spec
    return replace(spec, passes={m: tuple(p for p in ps if p not in SMOKE_ONLY_PASSES)
                                 for m, ps in spec.passes.items()})


def make_plan(spec: SceneSpec) -> Plan:
    line = timeline(spec)
    frames = {"rgb": rgb_frames(spec, line), "thermal": thermal_frames(spec, line)}
    k = {"rgb": intrinsics(spec.rig.rgb), "thermal": intrinsics(spec.rig.thermal)}
    optics = smoke_optics(POPULATIONS[spec.smoke.particles])
    render_passes = {m: tuple(p) for m, p in spec.passes.items()}
    return Plan(line, frames, k, optics, render_passes)


def resolve_asset_materials(spec: SceneSpec, manifest: Manifest, source: str) -> SceneSpec:
    """Give every object without a `material` its asset's default material from the manifest
    (appearance + thermal defaults, named `asset:NAME`), so the resolved spec is complete."""
    materials = dict(spec.materials)
    objects = []
    for i, obj in enumerate(spec.objects):
        if obj.material is None:
            asset = manifest.get(obj.asset, source, f"objects[{i}].asset")
            assert asset.material is not None
            materials.setdefault(asset.material.name, asset.material)
            obj = replace(obj, material=asset.material.name)
        objects.append(obj)
    return replace(spec, objects=tuple(objects), materials=materials)


def surface_radiance_curve(mat: MaterialSpec, sky_k: float) -> list[list[float]]:
    """(texture factor, leaving radiance) pairs: eps*L(T) + (1-eps)*L(T_sky), T set by the factor."""
    if mat.texture.kind == "none" or mat.temperature_variation_k == 0:
        factors = np.array([0.0])
    else:
        factors = np.linspace(0.0, 1.0, THERMAL_CURVE_POINTS)
    temps = mat.temperature_k + mat.temperature_variation_k * (factors - 0.5) * (len(factors) > 1)
    radiance = mat.emissivity * band_radiance(temps) + (1 - mat.emissivity) * band_radiance(sky_k)
    return [[float(f), float(r)] for f, r in zip(factors, np.atleast_1d(radiance))]


def smoke_coefficients(spec: SceneSpec, optics: SmokeOptics) -> dict[str, Any]:
    """Per-unit-grid-density coefficients (1/m). The luminance-weighted visible extinction is
    density*extinction_per_m; every other coefficient keeps Mie's ratio to it. The whole LWIR
    extinction is treated as absorption (its albedo is small; see docs/optics.md)."""
    scale = spec.smoke.density * spec.smoke.extinction_per_m / float(optics.extinction_visible)
    sca = scale * np.asarray(optics.scattering_rgb, dtype=float)
    ext = scale * np.asarray(optics.extinction_rgb, dtype=float)
    absorb = np.clip(ext - sca, 0.0, None)
    sca_max, abs_max = float(sca.max()), float(absorb.max())
    return {
        "scatter_density": sca_max,
        "scatter_color": (sca / sca_max if sca_max > 0 else np.zeros(3)).tolist(),
        "absorb_density": abs_max,
        "absorb_color": (1.0 - absorb / abs_max if abs_max > 0 else np.ones(3)).tolist(),
        "anisotropy": float(np.clip(optics.asymmetry_visible, -0.95, 0.95)),
        "lwir_absorption": scale * float(optics.extinction_lwir),
    }


def source_heat(temperature_k: float, ambient_k: float) -> float:
    """Blender's relative flow temperature: 50 K above ambient is one unit, clipped to ±10."""
    return float(np.clip((temperature_k - ambient_k) / 50.0, -10.0, 10.0))


def _fire(spec: SceneSpec) -> FireJob | None:
    if not spec.has_fire:
        return None
    ambient = spec.lights.ambient_temperature_k
    flame = max(s.temperature_k for s in spec.sources if s.kind in ("fire", "both"))
    factors = np.linspace(0.0, 1.0, THERMAL_CURVE_POINTS)
    radiance = band_radiance(ambient + factors * (flame - ambient))
    glow = glow_table(ambient, flame, FIRE_VISIBLE_STRENGTH, GLOW_TABLE_POINTS)
    return FireJob(ambient_k=ambient, flame_k=flame, visible_strength=FIRE_VISIBLE_STRENGTH,
                   glow_table=tuple((f, r, g, b) for f, r, g, b in glow),
                   radiance_curve=tuple((float(f), float(r)) for f, r in zip(factors, radiance)))


def effective_denoise(spec: SceneSpec, cam: CameraSpec) -> str:
    """The denoiser converges smoke; without smoke the smoky image is the clean one, exactly."""
    return cam.denoise if spec.has_smoke else "none"


def _camera(spec: SceneSpec, k: Intrinsics, supersample: int, cam: CameraSpec, frames: list[FrameSample],
            ) -> CameraJob:
    return CameraJob(
        render=ImageSize(k.width * supersample, k.height * supersample, k.fl_x * supersample),
        depth=ImageSize(k.width, k.height, k.fl_x),
        samples=cam.samples, clean_samples=cam.clean_samples, denoise=effective_denoise(spec, cam),
        volume_step_rate=cam.volume_step_rate,
        frames=tuple(FrameJob(stem=f.stem, blender_frame=f.base_frame, next_weight=f.next_weight,
                              c2w=tuple(tuple(float(v) for v in row) for row in f.c2w), split=f.split)
                     for f in frames),
    )


def load_scene_meshes(spec: SceneSpec, manifest: Manifest, source: str) -> dict[str, MeshArrays]:
    """Resolve every object's asset and load (checksum, check) each mesh file it uses. Done
    before anything is written, so a bad asset leaves nothing behind."""
    meshes: dict[str, MeshArrays] = {}
    for i, obj in enumerate(spec.objects):
        asset = manifest.get(obj.asset, source, f"objects[{i}].asset")
        if asset.kind == "file" and asset.name not in meshes:
            meshes[asset.name] = load_mesh(asset)
    return meshes


def _objects(spec: SceneSpec, manifest: Manifest, source: str, meshes: dict[str, MeshArrays],
             mesh_dir: Path) -> tuple[ObjectJob, ...]:
    out = []
    for i, obj in enumerate(spec.objects):
        asset = manifest.get(obj.asset, source, f"objects[{i}].asset")
        mesh_npz = None
        if asset.kind == "file":
            mesh = meshes[asset.name]
            npz = mesh_dir / f"{asset.name}.npz"
            if not npz.exists():
                with atomic_path(npz) as tmp:
                    np.savez(tmp, vertices=mesh.vertices, faces=mesh.faces)
            mesh_npz = str(npz)
        assert obj.material is not None, "resolve_asset_materials runs before the job is made"
        out.append(ObjectJob(name=obj.name, asset=AssetJob(asset.kind, dict(asset.params), asset.recipe, mesh_npz),
                             material=obj.material, location=obj.location, rotation_deg=obj.rotation_deg,
                             scale=obj.scale, params=dict(obj.params)))
    return tuple(out)


def shows_smoke(plan: Plan) -> bool:
    """Whether any requested pass shows the smoke; without one the worker builds no domain."""
    return any(p in SMOKE_PASSES for passes in plan.render_passes.values() for p in passes)


def make_job(spec: SceneSpec, plan: Plan, manifest: Manifest, source: str, work: Path, threads: int,
             meshes: dict[str, MeshArrays] | None = None) -> WorkerJob:
    """The worker's job; `meshes` are the already loaded mesh files (loaded here when not given).
    A job whose passes never show the smoke has no sources: no domain, no bake."""
    meshes = load_scene_meshes(spec, manifest, source) if meshes is None else meshes
    sky_k = spec.lights.sky_temperature_k
    coeffs = smoke_coefficients(spec, plan.optics)
    fire = _fire(spec)
    sources = spec.sources if shows_smoke(plan) else ()
    materials = {
        name: MaterialJob(name=name, base_color=mat.base_color, roughness=mat.roughness, metallic=mat.metallic,
                          texture=TextureJob(**vars(mat.texture)),
                          thermal_curve=tuple((f, r) for f, r in surface_radiance_curve(mat, sky_k)))
        for name, mat in spec.materials.items()}
    lights, sim = spec.lights, spec.sim
    return WorkerJob(
        seed=spec.seed,
        threads=threads,
        blend_path=str(work / "scene.blend"),
        cache_dir=str(work / "cache"),
        raw_dir=str(work / "raw"),
        summary_path=str(work / "worker_summary.json"),
        grids=(("density", "flame") if fire else ("density",)) if sources else (),
        materials=materials,
        objects=_objects(spec, manifest, source, meshes, work / "meshes"),
        world=WorldJob(sky_color=lights.sky_color, sky_strength=lights.sky_strength,
                       sun_strength=lights.sun_strength, sun_elevation_deg=lights.sun_elevation_deg,
                       sun_azimuth_deg=lights.sun_azimuth_deg, thermal_sky_radiance=float(band_radiance(sky_k))),
        sim=SimJob(fps=sim.fps, resolution=sim.resolution, center=sim.center, size=sim.size,
                   vorticity=sim.vorticity, buoyancy_density=sim.buoyancy_density, buoyancy_heat=sim.buoyancy_heat,
                   wind=sim.wind, dissolve_frames=int(round(sim.dissolve_s * sim.fps)), noise_upres=sim.noise_upres,
                   frame_end=plan.last_frame),
        sources=tuple(SourceJob(kind=s.kind, position=s.position, radius=s.radius, rate=s.rate,
                                heat=source_heat(s.temperature_k, lights.ambient_temperature_k), velocity=s.velocity)
                      for s in sources),
        smoke_rgb=RgbSmokeJob(scatter_density=coeffs["scatter_density"], scatter_color=tuple(coeffs["scatter_color"]),
                              absorb_density=coeffs["absorb_density"], absorb_color=tuple(coeffs["absorb_color"]),
                              anisotropy=coeffs["anisotropy"], fire=fire),
        smoke_thermal=ThermalSmokeJob(absorption_per_density=coeffs["lwir_absorption"],
                                      ambient_radiance=float(band_radiance(lights.ambient_temperature_k)), fire=fire),
        density_scale=spec.smoke.density_scale,
        cameras={
            "rgb": _camera(spec, plan.intrinsics["rgb"], 1, spec.rig.rgb, plan.frames["rgb"]),
            "thermal": _camera(spec, plan.intrinsics["thermal"], spec.rig.thermal.supersample, spec.rig.thermal,
                               plan.frames["thermal"]),
        },
        passes={m: tuple(p) for m, p in plan.render_passes.items() if p},
    )
