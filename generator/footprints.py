"""How much room an asset takes: its bounds from its parameters, without Blender, so the scene
sampler can place objects apart and keep them in view.

Primitives (`box`, `cylinder`, `sphere`) have exact bounds from their parameters. Composite
recipes are drawn at their manifest parameters only (the sampler varies them by `scale`), so
their bounds at those parameters are listed here as measured in Blender; mesh files give theirs
from their vertices. `tests/test_sampler.py` builds every asset the sampler uses in Blender and
checks these bounds against the real mesh.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from generator.assets import Asset, load_mesh

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Bounds:
    """Axis-aligned bounds of an object in its own frame (metres, before placement)."""

    lo: Vec3
    hi: Vec3

    def scaled(self, s: float) -> "Bounds":
        return Bounds(tuple(s * v for v in self.lo), tuple(s * v for v in self.hi))  # type: ignore[arg-type]

    def corners(self) -> np.ndarray:
        """The 8 corners, (8, 3)."""
        return np.array([[x, y, z] for x in (self.lo[0], self.hi[0]) for y in (self.lo[1], self.hi[1])
                         for z in (self.lo[2], self.hi[2])])


#: Bounds of composite recipes at their manifest parameters, measured from the built mesh.
RECIPE_BOUNDS: dict[str, Bounds] = {
    "chair": Bounds((-0.23, -0.22, 0.0), (0.23, 0.22, 0.96)),
    "table": Bounds((-0.6, -0.4, 0.0), (0.6, 0.4, 0.75)),
    "sofa": Bounds((-1.0, -0.45, 0.0), (1.0, 0.45, 0.8)),
    "bookshelf": Bounds((-0.5, -0.15, 0.0), (0.5, 0.15, 1.8)),
    "radiator": Bounds((-0.53, -0.045, 0.0), (0.53, 0.045, 0.7171)),
    "person": Bounds((-0.323, -0.17, 0.0), (0.323, 0.17, 1.762)),
    "grill": Bounds((-0.306, -0.306, 0.0064), (0.3692, 0.3136, 0.77)),
    "finned_cylinder": Bounds((-0.2, -0.2, 0.0), (0.2, 0.2, 0.35)),
    "tube_frame": Bounds((-0.366, -0.266, 0.0008), (0.366, 0.266, 0.6346)),
    "traffic_cone": Bounds((-0.2, -0.2, 0.0), (0.2, 0.2, 0.7)),
    "flower_pot": Bounds((-0.184, -0.184, -0.006), (0.184, 0.184, 0.3104)),
}


def _primitive_bounds(recipe: str, p: dict[str, Any]) -> Bounds | None:
    if recipe == "box":
        sx, sy, sz = (float(v) for v in p["dimensions"])
        return Bounds((-sx / 2, -sy / 2, 0.0), (sx / 2, sy / 2, sz))
    if recipe == "cylinder":
        r, depth = float(p["radius"]), float(p["depth"])
        return Bounds((-r, -r, 0.0), (r, r, depth))
    if recipe == "sphere":
        r = float(p["radius"])
        return Bounds((-r, -r, 0.0), (r, r, 2 * r))
    return None


_MESH_BOUNDS: dict[tuple[str, str], Bounds] = {}


def _mesh_bounds(asset: Asset) -> Bounds:
    """From the checked mesh file's vertices (read once per file and checksum)."""
    key = (str(asset.path), str(asset.sha256))
    if key not in _MESH_BOUNDS:
        vertices = load_mesh(asset).vertices
        _MESH_BOUNDS[key] = Bounds(tuple(vertices.min(axis=0)), tuple(vertices.max(axis=0)))  # type: ignore[arg-type]
    return _MESH_BOUNDS[key]


def local_bounds(asset: Asset, params: dict[str, Any]) -> Bounds:
    """Bounds of `asset` built with `params` (over its manifest parameters), at scale 1."""
    if asset.kind == "file":
        return _mesh_bounds(asset)
    merged = {**asset.params, **params}
    assert asset.recipe is not None
    exact = _primitive_bounds(asset.recipe, merged)
    if exact is not None:
        return exact
    if asset.name not in RECIPE_BOUNDS or merged != asset.params:
        raise ValueError(f"no bounds for asset {asset.name!r} with parameters {params!r}")
    return RECIPE_BOUNDS[asset.name]


@dataclass(frozen=True)
class Footprint:
    """An object standing on the ground: its bounds turned by `heading_deg` about +Z and
    scaled, then moved to `location`."""

    bounds: Bounds
    location: Vec3
    heading_deg: float
    scale: float

    def rotation(self) -> np.ndarray:
        a = math.radians(self.heading_deg)
        return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])

    def world_corners(self) -> np.ndarray:
        """The 8 corners of the placed bounds in world coordinates, (8, 3)."""
        return self.bounds.scaled(self.scale).corners() @ self.rotation().T + np.asarray(self.location)

    def rectangle(self) -> np.ndarray:
        """The ground rectangle the object covers, its 4 corners in order, (4, 2)."""
        b = self.bounds.scaled(self.scale)
        local = np.array([[b.lo[0], b.lo[1]], [b.hi[0], b.lo[1]], [b.hi[0], b.hi[1]], [b.lo[0], b.hi[1]]])
        return local @ self.rotation()[:2, :2].T + np.asarray(self.location[:2])


def rectangles_overlap(a: np.ndarray, b: np.ndarray, gap: float = 0.0) -> bool:
    """Whether two convex ground polygons (corners in order) come closer than `gap`: by the
    separating-axis theorem, they are apart when their projections on some edge normal are."""
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        for normal in np.stack([-edges[:, 1], edges[:, 0]], axis=1):
            normal = normal / np.linalg.norm(normal)
            pa, pb = a @ normal, b @ normal
            if pa.max() + gap <= pb.min() or pb.max() + gap <= pa.min():
                return False
    return True
