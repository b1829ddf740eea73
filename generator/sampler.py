"""`generate-scene --random SEED`: a complete scene spec drawn from a seed.

`draw_spec(seed, pins)` returns the same YAML-ready mapping a preset parses to, in the spec's
own key order (`SceneSpec.to_dict`), so the same seed and pins give the same bytes and the
YAML alone regenerates the dataset. The axes and their distributions are in
`generator.sampler_axes`, the materials in `generator.palette`; this module places objects,
sources and the drone (docs/generator.md, "The scene sampler").

- Objects stand on a ground plane, their ground rectangles (from `generator.footprints`) at
  least `GAP_M` apart, so no two meshes interpenetrate.
- The first object is warm (a person, an engine or a heater), so every scene has a thermal
  target; the rest are warm with probability 0.3.
- The drone's path is fitted to the layout: each object's whole bounding box is inside the
  RGB image in at least `IN_VIEW_SHARE` of the frames, and no camera is inside the smoke domain.
- The smoke's density is `smoke.optical_depth`, calibrated after the bake
  (generator.optical_depth); `extinction_per_m` only sets the pilot render's density.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from generator.assets import Manifest, load_manifest
from generator.errors import SpecError
from generator.footprints import Footprint, local_bounds, rectangles_overlap
from generator.palette import FINISHES, GROUNDS, draw_look, manifest_look, rounded, temperature
from generator.profiles import RANDOM_PROFILE
from generator.rig import intrinsics, rgb_frames, timeline
from generator.sampler_axes import Pin, draw_axes, stream
from generator.spec import SceneSpec, TrajectorySpec, parse_spec

MAX_SEED = 2**31 - 1  # the spec's seed field
IN_VIEW_SHARE = 0.8
GAP_M = 0.15
LAYOUT_FILL = 0.2
"""Objects are scattered over a disc whose area is their ground area over this fill."""
GROUND_SIZE_M = 60.0
NEAR_M = 0.05
CLEAN_SAMPLES = {"rgb": 64, "thermal": 32}
"""The random set's clean passes: 64 RGB samples (docs/generator.md, "The scene sampler")."""
THERMAL_SAMPLES = 8
EXTINCTION_PER_OPTICAL_DEPTH = 3.0
"""The pilot render's extinction per unit target optical depth (1/m per unit grid density): a
guess that puts the pilot near the target, so the calibration factor stays near 1."""


@dataclass(frozen=True)
class Kind:
    """A kind of object: its asset, thermal role, scale range, the palette finishes it may wear,
    the chance it wears its manifest look instead, and which primitive sizes it draws."""

    label: str
    asset: str
    role: str  # "ambient", "person" or "hot"
    scale: tuple[float, float] = (1.0, 1.0)
    finishes: tuple[str, ...] = ()
    own_look: float = 0.0
    sizes: str = ""


KINDS: tuple[Kind, ...] = (
    Kind("crate", "box", "ambient", finishes=("wood", "painted_metal", "plastic"), sizes="crate"),
    Kind("barrel", "cylinder", "ambient", finishes=("painted_metal", "plastic", "bare_metal"), sizes="barrel"),
    Kind("ball", "sphere", "ambient", finishes=("stone", "plastic"), sizes="ball"),
    Kind("chair", "chair", "ambient", (0.9, 1.1), ("wood", "plastic", "painted_metal"), 0.6),
    Kind("table", "table", "ambient", (0.9, 1.1), ("wood", "painted_metal"), 0.6),
    Kind("sofa", "sofa", "ambient", (0.9, 1.05), ("fabric",), 0.5),
    Kind("bookshelf", "bookshelf", "ambient", (0.8, 1.05), ("wood", "painted_metal"), 0.5),
    Kind("cone", "traffic_cone", "ambient", (0.8, 1.3), ("plastic",), 0.8),
    Kind("pot", "flower_pot", "ambient", (1.0, 2.0), ("stone", "plastic"), 0.6),
    Kind("frame", "tube_frame", "ambient", (1.0, 1.5), ("painted_metal",), 0.5),
    Kind("rock", "rock_a", "ambient", (0.5, 1.2), ("stone",), 0.7),
    Kind("rock", "rock_b", "ambient", (0.5, 1.2), ("stone",), 0.7),
    Kind("rock", "rock_c", "ambient", (0.5, 1.2), ("stone",), 0.7),
    Kind("person", "person", "person", (0.88, 1.1), ("fabric",), 0.5),
    Kind("engine", "finned_cylinder", "hot", (1.0, 2.2), ("bare_metal", "painted_metal"), 0.5),
    Kind("heater", "radiator", "hot", (0.8, 1.2), ("painted_metal",), 0.5),
    Kind("grill", "grill", "hot", (0.9, 1.1), ("painted_metal", "bare_metal"), 0.7),
    Kind("generator", "box", "hot", finishes=("painted_metal", "bare_metal"), sizes="generator"),
)
WARM_SHARE = 0.3


def _sizes(rng: np.random.Generator, sizes: str) -> dict[str, Any]:
    """Recipe parameters of the primitive kinds (metres)."""
    if sizes in ("crate", "generator"):
        lo, hi = ((0.3, 0.3, 0.3), (1.2, 1.2, 1.0)) if sizes == "crate" else ((0.5, 0.4, 0.4), (1.0, 0.7, 0.8))
        return {"dimensions": [rounded(rng.uniform(a, b)) for a, b in zip(lo, hi)]}
    if sizes == "barrel":
        return {"radius": rounded(rng.uniform(0.25, 0.4)), "depth": rounded(rng.uniform(0.6, 1.0))}
    if sizes == "ball":
        return {"radius": rounded(rng.uniform(0.2, 0.45))}
    return {}


@dataclass(frozen=True)
class Placed:
    name: str
    kind: Kind
    params: dict[str, Any]
    footprint: Footprint


def _choose_kind(rng: np.random.Generator, first: bool) -> Kind:
    warm = first or rng.random() < WARM_SHARE
    pool = [k for k in KINDS if (k.role != "ambient") == warm]
    return pool[int(rng.integers(len(pool)))]


def _place_objects(seed: int, count: int, manifest: Manifest) -> list[Placed]:
    """Scatter `count` objects over a disc, each at least GAP_M from the others."""
    rng = stream(seed, "layout")
    drawn = []
    for i in range(count):
        kind = _choose_kind(rng, i == 0)
        params = _sizes(rng, kind.sizes)
        scale = rounded(rng.uniform(*kind.scale))
        bounds = local_bounds(manifest.assets[kind.asset], params)
        drawn.append((kind, params, scale, bounds))
    area = sum((b.hi[0] - b.lo[0]) * (b.hi[1] - b.lo[1]) * s * s for _, _, s, b in drawn)
    radius = max(1.5, math.sqrt(area / (math.pi * LAYOUT_FILL)))
    placed: list[Placed] = []
    for i, (kind, params, scale, bounds) in enumerate(drawn):
        attempt = 0
        while True:
            if attempt and attempt % 100 == 0:
                radius *= 1.15
            attempt += 1
            r, angle = radius * math.sqrt(rng.random()), rng.uniform(0.0, 2 * math.pi)
            location = (rounded(r * math.cos(angle)), rounded(r * math.sin(angle)), rounded(-bounds.lo[2] * scale, 4))
            footprint = Footprint(bounds, location, rounded(rng.uniform(0.0, 360.0), 1), scale)
            if not any(rectangles_overlap(footprint.rectangle(), p.footprint.rectangle(), GAP_M) for p in placed):
                break
        placed.append(Placed(f"{kind.label}_{i}", kind, params, footprint))
    return placed


def _materials(seed: int, placed: list[Placed], ambient_k: float, manifest: Manifest) -> dict[str, dict[str, Any]]:
    """One material per object (named after it) and one for the ground."""
    rng = stream(seed, "materials")
    ground = draw_look(rng, GROUNDS[sorted(GROUNDS)[int(rng.integers(len(GROUNDS)))]])
    out = {"ground": {**ground, "temperature_k": rounded(ambient_k + rng.uniform(-2.0, 10.0), 2),
                      "temperature_variation_k": rounded(rng.uniform(1.0, 4.0), 1)}}
    for p in placed:
        asset = manifest.assets[p.kind.asset]
        if rng.random() < p.kind.own_look and asset.material is not None:
            look = manifest_look(asset.material)
        else:
            look = draw_look(rng, FINISHES[p.kind.finishes[int(rng.integers(len(p.kind.finishes)))]])
        t, variation = temperature(rng, p.kind.role, ambient_k, asset.thermal["temperature_k"])
        out[p.name] = {**look, "temperature_k": t, "temperature_variation_k": variation}
    return out


def _sources(seed: int, count: int, fire: bool, placed: list[Placed]) -> list[dict[str, Any]]:
    """Inflows on open ground among the objects (an emitter inside an obstacle would not emit)."""
    rng = stream(seed, "sources")
    reach = max(max(abs(c) for c in p.footprint.location[:2]) for p in placed) + 0.5
    out = []
    for i in range(count):
        burning = fire and i == 0
        radius = rounded(rng.uniform(0.2, 0.35))
        while True:
            x, y = (rounded(v) for v in rng.uniform(-reach, reach, 2))
            square = np.array([[x - radius, y - radius], [x + radius, y - radius], [x + radius, y + radius],
                               [x - radius, y + radius]])
            if not any(rectangles_overlap(square, p.footprint.rectangle(), 0.1) for p in placed):
                break
        heading = rng.uniform(0.0, 2 * math.pi)
        speed = rng.uniform(0.0, 0.5)
        out.append({"type": "both" if burning else "smoke", "position": [x, y, rounded(rng.uniform(0.1, 0.4))],
                    "radius": radius, "rate": rounded(rng.uniform(0.7, 1.0)),
                    "temperature_k": rounded(rng.uniform(900.0, 1300.0) if burning else rng.uniform(320.0, 420.0), 1),
                    "velocity": [rounded(speed * math.cos(heading)), rounded(speed * math.sin(heading)),
                                 rounded(rng.uniform(0.0, 0.6))]})
    return out


def _sim(seed: int, sources: list[dict[str, Any]], wind: float) -> dict[str, Any]:
    """The gas domain over the sources, stretched downwind."""
    rng = stream(seed, "sim")
    direction = rng.uniform(0.0, 2 * math.pi)
    wind_vector = np.array([math.cos(direction), math.sin(direction)]) * wind
    xy = np.array([s["position"][:2] for s in sources])
    lo, hi = xy.min(axis=0) - 1.2, xy.max(axis=0) + 1.2
    drift = 0.6 * wind_vector
    lo, hi = np.minimum(lo, lo + drift), np.maximum(hi, hi + drift)
    grow = np.maximum(0.0, 2.5 - (hi - lo)) / 2
    lo, hi = lo - grow, hi + grow
    height = rng.uniform(2.5, 3.5)
    return {"fps": 12, "resolution": RANDOM_PROFILE.overrides.sim_resolution,
            "center": [rounded((lo[0] + hi[0]) / 2), rounded((lo[1] + hi[1]) / 2), rounded(height / 2)],
            "size": [rounded(hi[0] - lo[0]), rounded(hi[1] - lo[1]), rounded(height)],
            "vorticity": rounded(rng.uniform(0.1, 1.0)), "buoyancy_heat": rounded(rng.uniform(0.6, 1.2)),
            "wind": [rounded(wind_vector[0]), rounded(wind_vector[1]), 0.0],
            "dissolve_s": rounded(rng.uniform(3.0, 8.0), 2), "warmup_s": rounded(rng.uniform(1.0, 2.0), 2)}


def in_view_shares(spec: SceneSpec, corners: list[np.ndarray]) -> np.ndarray:
    """For each object's bounding-box corners (8, 3), the share of RGB frames that see all of
    them inside the image (in front of the camera)."""
    k = intrinsics(spec.rig.rgb)
    inside = np.zeros((len(corners), spec.frames), dtype=bool)
    for j, frame in enumerate(rgb_frames(spec, timeline(spec))):
        rotation, position = frame.c2w[:3, :3], frame.c2w[:3, 3]
        for i, pts in enumerate(corners):
            cam = (pts - position) @ rotation  # world -> camera (+X right, +Y up, -Z forward)
            depth = -cam[:, 2]
            if np.any(depth < NEAR_M):
                continue
            u = k.cx + k.fl_x * cam[:, 0] / depth
            v = k.cy - k.fl_y * cam[:, 1] / depth
            inside[i, j] = bool(np.all((u >= 0) & (u <= k.width) & (v >= 0) & (v <= k.height)))
    return inside.mean(axis=1)


def cameras_clear_of(spec: SceneSpec, margin: float = 0.3) -> bool:
    """No RGB camera inside the smoke domain (grown by `margin`)."""
    lo = np.asarray(spec.sim.center) - np.asarray(spec.sim.size) / 2 - margin
    hi = np.asarray(spec.sim.center) + np.asarray(spec.sim.size) / 2 + margin
    return not any(np.all((f.c2w[:3, 3] > lo) & (f.c2w[:3, 3] < hi)) for f in rgb_frames(spec, timeline(spec)))


def _trajectory(rng: np.random.Generator, kind: str, centre: np.ndarray, distance: float) -> TrajectorySpec:
    """A path `distance` from the look-at centre, shaped by draws from `rng` (taken up front, so
    refitting the distance leaves the shape alone)."""
    def point(v: np.ndarray) -> tuple[float, float, float]:
        return tuple(rounded(c) for c in v)  # type: ignore[return-value]

    if kind == "orbit":
        elevation, start, sweep = rng.uniform(15.0, 40.0), rng.uniform(0.0, 360.0), rng.uniform(60.0, 150.0)
        sign = 1.0 if rng.random() < 0.5 else -1.0
        e = math.radians(elevation)
        return TrajectorySpec(kind="orbit", center=point(centre), radius=rounded(distance * math.cos(e)),
                              height=rounded(distance * math.sin(e)), start_deg=rounded(start, 1),
                              sweep_deg=rounded(sign * sweep, 1))
    heading, depression = rng.uniform(0.0, 2 * math.pi), math.radians(rng.uniform(25.0, 50.0))
    half_path, pan = rng.uniform(0.3, 0.6), rng.uniform(0.0, 0.5)
    view = np.array([math.cos(heading), math.sin(heading), 0.0])
    along = np.array([-view[1], view[0], 0.0])
    mid = centre + distance * (-math.cos(depression) * view + np.array([0.0, 0.0, math.sin(depression)]))
    return TrajectorySpec(kind="flyover", start=point(mid - half_path * distance * along),
                          end=point(mid + half_path * distance * along),
                          look_from=point(centre - pan * distance * along),
                          look_to=point(centre + pan * distance * along))


def _fit_rig(seed: int, spec: SceneSpec, kind: str, placed: list[Placed]) -> SceneSpec:
    """Move the drone out from the layout until every object is in view often enough and no
    camera is in the smoke domain."""
    rng = stream(seed, "trajectory")
    corners = [p.footprint.world_corners() for p in placed]
    every = np.concatenate(corners)
    centre = np.array([(every[:, 0].min() + every[:, 0].max()) / 2, (every[:, 1].min() + every[:, 1].max()) / 2,
                       0.35 * every[:, 2].max()])
    reach = float(np.linalg.norm(every - centre, axis=1).max())
    k = intrinsics(spec.rig.rgb)
    half_fov = min(math.atan(k.width / 2 / k.fl_x), math.atan(k.height / 2 / k.fl_y))
    distance = reach / math.sin(half_fov) * rng.uniform(0.75, 1.0)
    shape = rng.bit_generator.state
    for _ in range(80):
        rng.bit_generator.state = shape
        fitted = replace(spec, rig=replace(spec.rig, trajectory=_trajectory(rng, kind, centre, distance)))
        if in_view_shares(fitted, corners).min() >= IN_VIEW_SHARE and cameras_clear_of(fitted):
            return fitted
        distance *= 1.07
    raise RuntimeError(f"seed {seed}: no drone path keeps the objects in view")  # not reached: distance grows


def draw_spec(seed: int, pins: dict[str, Pin] | None = None, manifest: Manifest | None = None) -> dict[str, Any]:
    """The scene spec drawn from `seed` with `pins` applied, as YAML-ready data in the spec's
    key order (what `SceneSpec.to_yaml` writes)."""
    if not 0 <= seed <= MAX_SEED:
        raise SpecError("--random", "", f"the seed must be from 0 to {MAX_SEED}, got {seed}")
    manifest = manifest or load_manifest()
    axes = draw_axes(seed, pins)
    ambient = rounded(axes["lights.ambient_temperature_k"], 2)
    placed = _place_objects(seed, axes["objects.count"], manifest)
    sources = _sources(seed, axes["sources.count"], axes["fire"], placed)
    light_rng, rig_rng = stream(seed, "lights"), stream(seed, "rig")
    size = RANDOM_PROFILE.overrides
    width, height = size.resolution  # type: ignore[misc]
    scale = axes["thermal.scale"]
    fov = rig_rng.uniform(50.0, 65.0)
    baseline_angle = rig_rng.uniform(0.0, 2 * math.pi)
    baseline = axes["thermal.baseline_m"]
    target = axes["smoke.optical_depth"]
    raw = {
        "name": f"random_{seed}", "seed": seed, "frames": size.frames, "test_every": 8,
        "sim": _sim(seed, sources, axes["sim.wind"]),
        "smoke": {"density": 1.0, "extinction_per_m": rounded(EXTINCTION_PER_OPTICAL_DEPTH * target),
                  "particles": axes["smoke.particles"], "optical_depth": rounded(target, 4)},
        "sources": sources,
        "objects": [{"name": "ground", "asset": "ground_plane", "material": "ground",
                     "params": {"size": GROUND_SIZE_M}}]
        + [{"name": p.name, "asset": p.kind.asset, "material": p.name, "location": list(p.footprint.location),
            "rotation_deg": [0.0, 0.0, p.footprint.heading_deg], "scale": p.footprint.scale, "params": p.params}
           for p in placed],
        "materials": _materials(seed, placed, ambient, manifest),
        "lights": {"sun_strength": rounded(light_rng.uniform(2.5, 5.0), 2),
                   "sun_elevation_deg": rounded(axes["lights.sun_elevation_deg"], 1),
                   "sun_azimuth_deg": rounded(light_rng.uniform(0.0, 360.0), 1),
                   "sky_color": [rounded(v) for v in np.clip(np.array([0.55, 0.65, 0.85])
                                                             + light_rng.uniform(-0.08, 0.08, 3), 0.0, 1.0)],
                   "sky_strength": rounded(light_rng.uniform(0.5, 1.1), 2),
                   "sky_temperature_k": rounded(ambient - light_rng.uniform(25.0, 50.0), 2),
                   "ambient_temperature_k": ambient},
        "rig": {"trajectory": {"kind": axes["rig.trajectory"]},
                "rgb": {"width": width, "height": height, "fov_deg": rounded(fov, 2), "fps": 12.0,
                        "samples": size.samples, "clean_samples": CLEAN_SAMPLES["rgb"]},
                "thermal": {"width": max(4, round(scale * width)), "height": max(3, round(scale * height)),
                            "fov_deg": rounded(fov * rig_rng.uniform(0.8, 1.0), 2), "fps": 9.0,
                            "time_offset_s": rounded(axes["thermal.time_offset_s"], 4),
                            "baseline_m": [rounded(baseline * math.cos(baseline_angle), 4),
                                           rounded(baseline * math.sin(baseline_angle), 4), 0.0],
                            "samples": THERMAL_SAMPLES, "clean_samples": CLEAN_SAMPLES["thermal"], "supersample": 2}},
        "passes": ["rgb", "thermal"],
    }
    spec = parse_spec(raw, f"random scene {seed}")
    return _fit_rig(seed, spec, axes["rig.trajectory"], placed).to_dict()
