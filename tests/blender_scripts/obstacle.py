"""Bakes the demo's plume with a slab held over its source, with the generator's own job and
scene builder, once with the scene's objects as Mantaflow obstacles and once without, and
writes the mean smoke density inside the slab and in the air just below and beside it.
Run in a subprocess: python obstacle.py OUT.json WORK_DIR
"""
import json
import os
import sys
from dataclasses import replace
from pathlib import Path

import bpy
import numpy as np

from blender import scene as scene_mod
from blender.job import WorkerJob
from blender.manta_repair import repair_manta_hierarchy
from generator.api import resolve_spec
from generator.assets import load_manifest
from generator.job import make_job, make_plan, resolve_asset_materials
from generator.spec import ObjectSpec

#: A 1.2 x 1.2 x 0.4 m slab whose underside is 0.8 m above the source's centre.
SLAB_LOW, SLAB_HIGH = np.array([-0.6, -0.6, 1.05]), np.array([0.6, 0.6, 1.45])


def density_at_last_frame(job: WorkerJob, obstacles: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Density (z, y, x) and the world bounds of the domain."""
    scene_mod.reset()
    original = scene_mod.add_obstacles
    if not obstacles:
        scene_mod.add_obstacles = lambda objects, built: None
    built = scene_mod.build(job)
    scene_mod.add_obstacles = original
    scene_mod.bake(built.domain)
    scene = bpy.context.scene
    scene.frame_set(job.sim.frame_end)
    dom = bpy.data.objects[built.domain]
    settings = dom.evaluated_get(bpy.context.evaluated_depsgraph_get()).modifiers["Fluid"].domain_settings
    nx, ny, nz = settings.domain_resolution
    grid = np.array(settings.density_grid).reshape(nz, ny, nx)
    corners = np.array([dom.matrix_world @ v.co for v in dom.data.vertices])
    return grid, corners.min(axis=0), corners.max(axis=0)


def region_means(grid: np.ndarray, low: np.ndarray, high: np.ndarray) -> dict[str, float]:
    nz, ny, nx = grid.shape
    step = (high - low) / np.array([nx, ny, nz])
    centres = [low[a] + (np.arange(n) + 0.5) * step[a] for a, n in enumerate((nx, ny, nz))]
    z, y, x = np.meshgrid(centres[2], centres[1], centres[0], indexing="ij")
    margin = step.max()  # one voxel: cells cut by the surface are neither inside nor outside
    inside = ((x > SLAB_LOW[0] + margin) & (x < SLAB_HIGH[0] - margin) & (y > SLAB_LOW[1] + margin)
              & (y < SLAB_HIGH[1] - margin) & (z > SLAB_LOW[2] + margin) & (z < SLAB_HIGH[2] - margin))
    grown_low, grown_high = SLAB_LOW - 3 * margin, SLAB_HIGH + 3 * margin
    near = ((x > grown_low[0]) & (x < grown_high[0]) & (y > grown_low[1]) & (y < grown_high[1])
            & (z > grown_low[2]) & (z < grown_high[2]))
    outside = ((x < SLAB_LOW[0] - margin) | (x > SLAB_HIGH[0] + margin) | (y < SLAB_LOW[1] - margin)
               | (y > SLAB_HIGH[1] + margin) | (z < SLAB_LOW[2] - margin) | (z > SLAB_HIGH[2] + margin))
    shell = near & outside
    below = (near & (z < SLAB_LOW[2] - margin) & (x > SLAB_LOW[0]) & (x < SLAB_HIGH[0])
             & (y > SLAB_LOW[1]) & (y < SLAB_HIGH[1]))
    return {"inside_mean": float(grid[inside].mean()), "inside_max": float(grid[inside].max()),
            "shell_mean": float(grid[shell].mean()), "below_mean": float(grid[below].mean()),
            "inside_cells": int(inside.sum()), "shell_cells": int(shell.sum()), "below_cells": int(below.sum()),
            "domain_mean": float(grid.mean())}


def main() -> None:
    out, work = sys.argv[1], Path(sys.argv[2])
    repair_manta_hierarchy()
    spec, source = resolve_spec("demo")
    size = (SLAB_HIGH - SLAB_LOW).tolist()
    slab = ObjectSpec(name="slab", asset="box", material="concrete", location=(0.0, 0.0, float(SLAB_LOW[2])),
                      params={"dimensions": size, "bevel": 0.0})
    spec = replace(spec, frames=2, objects=(*spec.objects[:1], slab))
    manifest = load_manifest()
    spec = resolve_asset_materials(spec, manifest, source)
    results = {}
    for label, obstacles in (("with_obstacles", True), ("without_obstacles", False)):
        job = make_job(spec, make_plan(spec), manifest, source, work / label, 1)
        grid, low, high = density_at_last_frame(job, obstacles)
        results[label] = region_means(grid, low, high)
    with open(out, "w") as fh:
        json.dump(results, fh)
    sys.stdout.flush()
    os._exit(0)


main()
