"""Where a Mantaflow bake lives, and when one is reused.

A bake (the saved scene and its Mantaflow cache) depends on what the worker's bake stage
builds: objects, materials, lights, the simulation, the sources and the smoke materials, and
on the code that builds it. It does not depend on the cameras, the passes, the render seed or
the density scale, which only the render stage reads. `bake_key` hashes exactly the former,
so datasets that differ only in the latter (one scene at several smoke densities, or at
another image size) share one simulation when they share a bake store.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from blender.job import WorkerJob, built_scene_path

#: Job fields the bake stage never reads: rendering, bookkeeping, and where files go.
RENDER_ONLY_FIELDS = ("seed", "threads", "blend_path", "cache_dir", "raw_dir", "summary_path", "grids",
                      "density_scale", "cameras", "passes")


def _mesh_digest(npz: str) -> str:
    """A mesh file's arrays, by content: its path lies in a per-dataset staging folder."""
    digest = hashlib.sha256()
    with np.load(npz) as data:
        for name in ("vertices", "faces"):
            array = np.ascontiguousarray(data[name])
            digest.update(f"{name}:{array.dtype.str}:{array.shape}".encode())
            digest.update(array.tobytes())
    return digest.hexdigest()


def bake_key(job: WorkerJob, code: str) -> str:
    """SHA-256 of what the bake stage reads from `job` (mesh files by content) and of `code`,
    the digest of the code that builds and bakes the scene."""
    data = job.to_data()
    for name in RENDER_ONLY_FIELDS:
        data.pop(name)
    for obj in data["objects"]:
        if obj["asset"]["mesh_npz"] is not None:
            obj["asset"]["mesh_npz"] = _mesh_digest(obj["asset"]["mesh_npz"])
    text = json.dumps({"job": data, "code": code}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def bake_folder(store: Path, scene: str, key: str) -> Path:
    return store / f"{scene}.{key[:16]}"


def bake_in(job: WorkerJob, folder: Path) -> WorkerJob:
    """The job with its saved scene and Mantaflow cache in `folder`."""
    return replace(job, blend_path=str(folder / "scene.blend"), cache_dir=str(folder / "cache"))


def is_baked(job: WorkerJob) -> bool:
    """True once the bake stage has finished."""
    return Path(job.blend_path).is_file() and built_scene_path(job.blend_path).is_file()
