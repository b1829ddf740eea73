"""Builds, with the generator's own recipes and mesh loading, (1) every asset the scene sampler
uses, at the parameters given, and writes each built mesh's bounds; (2) the objects of drawn
scenes, placed as their specs say, and writes every pair of objects whose triangles intersect
(Blender's BVH overlap test) and each object's lowest point.
Run in a subprocess: python sampler_meshes.py OUT.json WORK_DIR REQUEST.json
REQUEST: {"assets": [[label, asset, params], ...], "scenes": [spec data, ...]}
"""
import json
import math
import os
import sys

import bpy  # noqa: F401
import numpy as np
from mathutils import Euler
from mathutils.bvhtree import BVHTree

from blender.recipes import RECIPES, mesh_from_arrays
from blender.scene import reset
from generator.assets import load_manifest, load_mesh


def build(manifest, name: str, asset_name: str, params: dict):
    asset = manifest.assets[asset_name]
    if asset.kind == "file":
        mesh = load_mesh(asset)
        return mesh_from_arrays(name, mesh.vertices, mesh.faces)
    return RECIPES[asset.recipe](name, {**asset.params, **params})


def world_vertices(obj) -> np.ndarray:
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out = []
    for part in [obj, *obj.children_recursive]:
        if part.type != "MESH":
            continue
        evaluated = part.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        co = np.empty(len(mesh.vertices) * 3)
        mesh.vertices.foreach_get("co", co)
        matrix = np.array(part.matrix_world)
        out.append(co.reshape(-1, 3) @ matrix[:3, :3].T + matrix[:3, 3])
        evaluated.to_mesh_clear()
    return np.concatenate(out)


def main() -> None:
    out, request = sys.argv[1], json.loads(open(sys.argv[3]).read())
    manifest = load_manifest()
    bounds = []
    for label, asset_name, params in request["assets"]:
        reset()
        v = world_vertices(build(manifest, label, asset_name, params))
        bounds.append({"label": label, "asset": asset_name, "params": params, "lo": v.min(axis=0).tolist(),
                       "hi": v.max(axis=0).tolist()})
    scenes = []
    for spec in request["scenes"]:
        reset()
        objects = []
        for o in spec["objects"]:
            if o["asset"] == "ground_plane":
                continue
            obj = build(manifest, o["name"], o["asset"], o["params"])
            obj.location = o["location"]
            obj.rotation_euler = Euler([math.radians(a) for a in o["rotation_deg"]])
            obj.scale = o["scale"]
            bpy.context.view_layer.update()
            bpy.ops.object.select_all(action="DESELECT")
            obj.select_set(True)
            bpy.context.view_layer.objects.active = obj
            bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
            objects.append(obj)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        trees = {obj.name: BVHTree.FromObject(obj, depsgraph) for obj in objects}
        names = sorted(trees)
        overlaps = [[a, b] for i, a in enumerate(names) for b in names[i + 1:] if trees[a].overlap(trees[b])]
        lowest = {obj.name: float(world_vertices(obj)[:, 2].min()) for obj in objects}
        scenes.append({"name": spec["name"], "objects": len(objects), "overlaps": overlaps, "lowest": lowest})
    with open(out, "w") as fh:
        json.dump({"bounds": bounds, "scenes": scenes}, fh)
    sys.stdout.flush()
    os._exit(0)


main()
