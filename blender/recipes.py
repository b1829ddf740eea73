"""Procedural asset recipes: Blender primitives and modifiers, one function per recipe.

A recipe takes the object name and its manifest/spec `params` and returns a new mesh
object at the origin with unit transform; placement happens in the scene builder.
"""
from __future__ import annotations

from typing import Any, Callable

import bpy
import numpy as np

Recipe = Callable[[str, dict[str, Any]], bpy.types.Object]
RECIPES: dict[str, Recipe] = {}


def recipe(name: str) -> Callable[[Recipe], Recipe]:
    def register(fn: Recipe) -> Recipe:
        RECIPES[name] = fn
        return fn

    return register


def _named(obj: bpy.types.Object, name: str) -> bpy.types.Object:
    obj.name = name
    obj.data.name = name
    return obj


def _bevel(obj: bpy.types.Object, width: float, segments: int = 2) -> None:
    if width > 0:
        mod = obj.modifiers.new("Bevel", "BEVEL")
        mod.width = width
        mod.segments = segments


@recipe("ground_plane")
def ground_plane(name: str, p: dict[str, Any]) -> bpy.types.Object:
    bpy.ops.mesh.primitive_plane_add(size=float(p.get("size", 10.0)))
    return _named(bpy.context.object, name)


@recipe("box")
def box(name: str, p: dict[str, Any]) -> bpy.types.Object:
    sx, sy, sz = (float(v) for v in p.get("dimensions", (1.0, 1.0, 1.0)))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, sz / 2.0))
    obj = _named(bpy.context.object, name)
    obj.scale = (sx, sy, sz)
    bpy.ops.object.transform_apply(location=True, scale=True)
    _bevel(obj, float(p.get("bevel", 0.02)))
    return obj


@recipe("sphere")
def sphere(name: str, p: dict[str, Any]) -> bpy.types.Object:
    radius = float(p.get("radius", 0.5))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, segments=int(p.get("segments", 32)),
                                         ring_count=int(p.get("rings", 16)), location=(0.0, 0.0, radius))
    obj = _named(bpy.context.object, name)
    bpy.ops.object.transform_apply(location=True)
    bpy.ops.object.shade_smooth()
    return obj


@recipe("cylinder")
def cylinder(name: str, p: dict[str, Any]) -> bpy.types.Object:
    radius, depth = float(p.get("radius", 0.4)), float(p.get("depth", 1.0))
    bpy.ops.mesh.primitive_cylinder_add(radius=radius, depth=depth, vertices=int(p.get("vertices", 32)),
                                        location=(0.0, 0.0, depth / 2.0))
    obj = _named(bpy.context.object, name)
    bpy.ops.object.transform_apply(location=True)
    _bevel(obj, float(p.get("bevel", 0.01)))
    return obj


def mesh_from_arrays(name: str, vertices: np.ndarray, faces: np.ndarray) -> bpy.types.Object:
    """A mesh object from trimesh-checked arrays (metres), without Blender's importers."""
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", np.asarray(vertices, dtype=np.float32).ravel())
    faces = np.asarray(faces, dtype=np.int32)
    mesh.loops.add(faces.size)
    mesh.loops.foreach_set("vertex_index", faces.ravel())
    mesh.polygons.add(len(faces))
    mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    mesh.polygons.foreach_set("loop_total", np.full(len(faces), 3, dtype=np.int32))
    mesh.update(calc_edges=True)
    mesh.validate()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj
