"""`assets_manifest.yaml`: every asset a scene may reference, and the checks on mesh files.

Only the assets a scene references are resolved, and only their files are read.
Mesh files are loaded with trimesh (OBJ, GLB, PLY, STL...), checked (checksum, bounds,
degenerate faces), converted to metres, and handed to the Blender worker as arrays.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from generator.errors import AssetError, SpecError
from generator.fields import Fields
from generator.spec import MaterialSpec, parse_texture

UNIT_SCALE = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
MANIFEST_ENV = "SMOKESEER_ASSETS_MANIFEST"
MAX_EXTENT_M = 500.0


@dataclass(frozen=True)
class Asset:
    name: str
    kind: str  # "recipe" | "file"
    units: str
    license: str
    provenance: str
    recipe: str | None = None
    path: Path | None = None
    sha256: str | None = None
    params: dict[str, Any] = field(default_factory=dict)
    thermal: dict[str, float] = field(default_factory=dict)
    material: MaterialSpec | None = None  # "asset:NAME", for objects whose spec names no material


def default_manifest_path() -> Path:
    env = os.environ.get(MANIFEST_ENV)
    return Path(env) if env else Path(__file__).resolve().parents[1] / "assets_manifest.yaml"


def _asset(name: str, f: Fields, root: Path) -> Asset:
    kind = f.string("kind", choices=("recipe", "file"))
    units = f.string("units", "m", tuple(UNIT_SCALE))
    thermal_f = f.sub("thermal")
    thermal = {
        "temperature_k": thermal_f.number("temperature_k", 293.15, 0.0, 5000.0, exclusive_minimum=True),
        "emissivity": thermal_f.number("emissivity", 0.95, 0.0, 1.0),
        "temperature_variation_k": thermal_f.number("temperature_variation_k", 0.0, 0.0, 500.0),
    }
    if thermal["temperature_k"] - thermal["temperature_variation_k"] / 2 <= 0:
        raise thermal_f.error("temperature_variation_k", "would take the temperature to 0 K or below")
    thermal_f.finish()
    look = f.sub("appearance")
    material = MaterialSpec(
        name=f"asset:{name}",
        base_color=look.vector("base_color", 3, (0.5, 0.5, 0.5), 0.0, 1.0),
        roughness=look.number("roughness", 0.6, 0.0, 1.0),
        metallic=look.number("metallic", 0.0, 0.0, 1.0),
        texture=parse_texture(look.sub("texture")),
        **thermal,
    )
    look.finish()
    common = dict(name=name, kind=kind, units=units, license=f.string("license"),
                  provenance=f.string("provenance"), params=f.mapping("params"), thermal=thermal,
                  material=material)
    if kind == "recipe":
        asset = Asset(**common, recipe=f.string("recipe"))
    else:
        raw_sha = f.raw("sha256", None)
        if isinstance(raw_sha, (int, float)) and not isinstance(raw_sha, bool):
            raise f.error("sha256", f"YAML read this digest as a number ({raw_sha!r}); write it in quotes, "
                                    "e.g. sha256: \"0123...\"")
        sha = f.string("sha256")
        if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise f.error("sha256", "must be 64 lowercase hex digits")
        asset = Asset(**common, path=(root / f.string("path")).resolve(), sha256=sha)
    f.finish()
    return asset


@dataclass(frozen=True)
class Manifest:
    path: Path
    assets: dict[str, Asset]

    def get(self, name: str, source: str, field_name: str) -> Asset:
        if name not in self.assets:
            raise SpecError(source, field_name, f"unknown asset {name!r}: not in {self.path}")
        return self.assets[name]


def load_manifest(path: Path | None = None) -> Manifest:
    path = path or default_manifest_path()
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise SpecError(path, "", f"cannot read the assets manifest: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise SpecError(path, "", f"malformed YAML: {str(exc).splitlines()[0]}") from None
    top = Fields(data, str(path))
    top.integer("version", 1, 1, 1)
    assets = {name: _asset(name, f, path.parent) for name, f in top.sub_map("assets").items()}
    top.finish()
    return Manifest(path, assets)


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass(frozen=True)
class MeshArrays:
    vertices: np.ndarray  # (V, 3) float64, metres
    faces: np.ndarray  # (F, 3) int64
    removed_degenerate: int


def load_mesh(asset: Asset) -> MeshArrays:
    """Checksum, load with trimesh, drop degenerate faces, convert to metres, check bounds."""
    import trimesh

    assert asset.path is not None and asset.sha256 is not None
    if not asset.path.is_file():
        raise AssetError(f"{asset.path}: asset {asset.name!r} is missing (listed in the manifest)")
    actual = sha256_of(asset.path)
    if actual != asset.sha256:
        raise AssetError(f"{asset.path}: sha256 mismatch for asset {asset.name!r}: manifest says "
                         f"{asset.sha256}, file is {actual}")
    try:
        mesh = trimesh.load(asset.path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise AssetError(f"{asset.path}: cannot load asset {asset.name!r} as a mesh: {exc}") from None
    faces = np.asarray(mesh.faces, dtype=np.int64)
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * UNIT_SCALE[asset.units]
    if len(faces) == 0 or not np.isfinite(vertices).all():
        raise AssetError(f"{asset.path}: asset {asset.name!r} has no faces or non-finite vertices")
    tri = vertices[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    scale = max(float(np.ptp(vertices, axis=0).max()), 1e-12)
    keep = area2 > 1e-12 * scale * scale
    if not keep.any():
        raise AssetError(f"{asset.path}: every face of asset {asset.name!r} is degenerate")
    extent = np.ptp(vertices, axis=0)
    if extent.max() > MAX_EXTENT_M or extent.max() < 1e-3:
        raise AssetError(f"{asset.path}: asset {asset.name!r} spans {extent.max():.4g} m with units "
                         f"{asset.units!r}: check the manifest's units")
    return MeshArrays(vertices, faces[keep], int((~keep).sum()))
