"""Procedural mesh assets made with numpy + trimesh and committed as PLY files.

Terrain heightfields and noise-displaced rocks are generated here rather than in Blender
so that the files are plain data any tool can read, listed in `assets_manifest.yaml` with
a sha256. Every random number comes from an integer hash of lattice coordinates and a
seed, and the PLY writer is our own (fixed header, little-endian float32/int32), so
`python -m generator.meshgen` rewrites byte-identical files on any platform with IEEE
floats. `--check` regenerates into a temporary folder and compares with the manifest.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from contracts.atomic import atomic_path

MESH_DIR = Path(__file__).resolve().parents[1] / "assets" / "meshes"
_MASK64 = np.uint64(0xFFFFFFFFFFFFFFFF)


@dataclass(frozen=True)
class TerrainRecipe:
    """A square heightfield centred on the origin, z up, with a gentle clearing in the middle
    (where a preset stands its subject) and stronger relief and craters outside it."""

    size_m: float = 40.0
    cells: int = 48
    relief_m: float = 3.0
    feature_m: float = 14.0
    octaves: int = 5
    clearing_radius_m: float = 8.0
    clearing_relief_m: float = 0.3
    craters: int = 0
    crater_radius_m: tuple[float, float] = (1.5, 4.0)
    seed: int = 0


@dataclass(frozen=True)
class RockRecipe:
    """An icosphere displaced along its radius by fractal noise, stretched and cut flat at
    the bottom so that it rests on the ground; its lowest point is z = 0."""

    radius_m: float = 0.5
    subdivisions: int = 3
    roughness: float = 0.3
    stretch: tuple[float, float, float] = (1.0, 1.0, 1.0)
    flatten: float = 0.25
    seed: int = 0


MeshRecipe = TerrainRecipe | RockRecipe

RECIPES: dict[str, MeshRecipe] = {
    "forest_terrain": TerrainRecipe(size_m=70.0, cells=48, relief_m=5.0, feature_m=22.0, octaves=5,
                                    clearing_radius_m=16.0, clearing_relief_m=0.5, seed=11),
    "mars_terrain": TerrainRecipe(size_m=44.0, cells=48, relief_m=2.5, feature_m=12.0, octaves=6,
                                  clearing_radius_m=6.0, clearing_relief_m=0.25, craters=7,
                                  crater_radius_m=(1.5, 4.5), seed=23),
    "rock_a": RockRecipe(radius_m=0.5, subdivisions=3, roughness=0.35, stretch=(1.3, 1.0, 0.75),
                         flatten=0.3, seed=1),
    "rock_b": RockRecipe(radius_m=0.5, subdivisions=3, roughness=0.5, stretch=(1.0, 0.9, 0.9),
                         flatten=0.2, seed=2),
    "rock_c": RockRecipe(radius_m=0.5, subdivisions=3, roughness=0.25, stretch=(1.6, 0.8, 0.55),
                         flatten=0.35, seed=3),
}


def _hash01(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """A uniform value in [0, 1) per integer lattice point (splitmix64 finaliser)."""
    with np.errstate(over="ignore"):
        h = (ix.astype(np.int64).astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
             ^ iy.astype(np.int64).astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
             ^ iz.astype(np.int64).astype(np.uint64) * np.uint64(0x165667B19E3779F9)
             ^ np.uint64(seed) * np.uint64(0x27D4EB2F165667C5)) & _MASK64
        h = ((h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & _MASK64
        h = ((h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & _MASK64
        h = h ^ (h >> np.uint64(31))
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def value_noise(points: np.ndarray, seed: int) -> np.ndarray:
    """Trilinear-quintic value noise in [0, 1] at (N, 3) points, lattice spacing 1."""
    base = np.floor(points)
    frac = points - base
    w = frac * frac * frac * (frac * (frac * 6.0 - 15.0) + 10.0)
    i = base.astype(np.int64)
    out = np.zeros(len(points))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                weight = ((w[:, 0] if dx else 1 - w[:, 0]) * (w[:, 1] if dy else 1 - w[:, 1])
                          * (w[:, 2] if dz else 1 - w[:, 2]))
                out += weight * _hash01(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


def fbm(points: np.ndarray, octaves: int, seed: int) -> np.ndarray:
    """Fractal sum of value noise, normalised to [-1, 1] (mean ~0)."""
    total, amplitude, norm = np.zeros(len(points)), 1.0, 0.0
    for k in range(octaves):
        total += amplitude * (2.0 * value_noise(points * (2.0 ** k), seed + 7919 * k) - 1.0)
        norm += amplitude
        amplitude *= 0.5
    return total / norm


def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def terrain_height(recipe: TerrainRecipe, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The continuous height function the grid samples (metres)."""
    pts = np.stack([x / recipe.feature_m, y / recipe.feature_m, np.zeros_like(x)], axis=-1).reshape(-1, 3)
    fine = np.stack([x / 2.0, y / 2.0, np.full_like(x, 0.5)], axis=-1).reshape(-1, 3)
    r = np.hypot(x, y).ravel()
    outside = _smoothstep(recipe.clearing_radius_m, recipe.clearing_radius_m * 1.8, r)
    h = (recipe.clearing_relief_m * fbm(fine, 3, recipe.seed + 1)
         + outside * recipe.relief_m * fbm(pts, recipe.octaves, recipe.seed))
    if recipe.craters:
        rng = np.random.default_rng(recipe.seed)
        for _ in range(recipe.craters):
            angle = rng.uniform(0.0, 2.0 * np.pi)
            dist = rng.uniform(recipe.clearing_radius_m * 1.4, recipe.size_m * 0.45)
            radius = rng.uniform(*recipe.crater_radius_m)
            depth = 0.25 * radius
            d = np.hypot(x.ravel() - dist * np.cos(angle), y.ravel() - dist * np.sin(angle)) / radius
            h += np.where(d < 1.0, -depth * (1.0 - d * d), 0.0) + 0.35 * depth * np.exp(-((d - 1.0) / 0.3) ** 2)
    return h.reshape(np.shape(x))


def terrain_mesh(recipe: TerrainRecipe) -> trimesh.Trimesh:
    n = recipe.cells + 1
    coords = np.linspace(-recipe.size_m / 2.0, recipe.size_m / 2.0, n)
    gx, gy = np.meshgrid(coords, coords, indexing="xy")
    vertices = np.stack([gx, gy, terrain_height(recipe, gx, gy)], axis=-1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    v00, v10, v01, v11 = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = np.concatenate([np.stack([v00, v10, v11], -1).reshape(-1, 3),
                            np.stack([v00, v11, v01], -1).reshape(-1, 3)])
    return trimesh.Trimesh(vertices.astype(np.float32), faces, process=False)


def sample_terrain(recipe: TerrainRecipe, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
    """Height of the triangulated grid, exactly as written to the PLY, under points (x, y):
    where a preset must stand an object so that it touches the ground."""
    n = recipe.cells
    heights = np.asarray(terrain_mesh(recipe).vertices[:, 2], dtype=np.float64).reshape(n + 1, n + 1)
    step = recipe.size_m / n
    u = (np.asarray(x, dtype=float) + recipe.size_m / 2) / step
    v = (np.asarray(y, dtype=float) + recipe.size_m / 2) / step
    if np.any((u < 0) | (u > n) | (v < 0) | (v > n)):
        raise ValueError(f"points outside the {recipe.size_m} m terrain")
    i, j = np.minimum(u.astype(int), n - 1), np.minimum(v.astype(int), n - 1)
    fu, fv = u - i, v - j
    h00, h10, h01, h11 = heights[j, i], heights[j, i + 1], heights[j + 1, i], heights[j + 1, i + 1]
    lower = h00 + fu * (h10 - h00) + fv * (h11 - h10)
    upper = h00 + fv * (h01 - h00) + fu * (h11 - h01)
    return np.where(fu >= fv, lower, upper)


def rock_mesh(recipe: RockRecipe) -> trimesh.Trimesh:
    sphere = trimesh.creation.icosphere(subdivisions=recipe.subdivisions, radius=1.0)
    unit = np.asarray(sphere.vertices, dtype=np.float64)
    bump = fbm(unit * 1.6 + 10.0 * recipe.seed, 4, recipe.seed)
    v = unit * (1.0 + recipe.roughness * bump)[:, None] * np.asarray(recipe.stretch) * recipe.radius_m
    z_lo, z_hi = v[:, 2].min(), v[:, 2].max()
    v[:, 2] = np.maximum(v[:, 2], z_lo + recipe.flatten * (z_hi - z_lo))
    v[:, 2] -= v[:, 2].min()
    return trimesh.Trimesh(v.astype(np.float32), np.asarray(sphere.faces), process=False)


def build_mesh(recipe: MeshRecipe) -> trimesh.Trimesh:
    return terrain_mesh(recipe) if isinstance(recipe, TerrainRecipe) else rock_mesh(recipe)


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, comment: str) -> None:
    """Binary little-endian PLY with a fixed header: the bytes depend on the arrays only."""
    header = (f"ply\nformat binary_little_endian 1.0\ncomment {comment}\n"
              f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    face_rows = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face_rows["n"] = 3
    face_rows["i"] = faces
    with atomic_path(path) as tmp, tmp.open("wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.ascontiguousarray(vertices, dtype="<f4").tobytes())
        fh.write(face_rows.tobytes())


def write_all(out_dir: Path = MESH_DIR) -> dict[str, Path]:
    """Write every recipe's PLY into `out_dir`; returns name -> path."""
    paths = {}
    for name, recipe in RECIPES.items():
        mesh = build_mesh(recipe)
        path = out_dir / f"{name}.ply"
        write_ply(path, mesh.vertices, mesh.faces, f"smokeseer-synth generator/meshgen.py {name} units m")
        paths[name] = path
    return paths


def main(argv: list[str] | None = None) -> int:
    from generator.assets import load_manifest, sha256_of

    p = argparse.ArgumentParser(prog="python -m generator.meshgen",
                                description="Regenerate the committed PLY mesh assets (assets/meshes/).")
    p.add_argument("--out", type=Path, default=MESH_DIR, help="output folder (default: assets/meshes)")
    p.add_argument("--check", action="store_true",
                   help="regenerate into a temporary folder and compare with the manifest's sha256")
    args = p.parse_args(argv)
    if args.check:
        manifest = load_manifest()
        by_file = {a.path.name: a for a in manifest.assets.values() if a.kind == "file" and a.path}
        with tempfile.TemporaryDirectory() as tmp:
            bad = 0
            for name, path in write_all(Path(tmp)).items():
                asset = by_file.get(path.name)
                digest = sha256_of(path)
                ok = asset is not None and asset.sha256 == digest
                bad += not ok
                print(f"{name}: {'ok' if ok else 'MISMATCH'} {digest}")
        return 1 if bad else 0
    for name, path in write_all(args.out).items():
        mesh = trimesh.load(path, process=False)
        print(f"{name}: {path} {path.stat().st_size} bytes, {len(mesh.vertices)} vertices, "
              f"{len(mesh.faces)} faces, sha256 {sha256_of(path)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
