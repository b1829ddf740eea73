"""The Blender worker process: `python -m blender.worker JOB.json {bake|render}`.

`bake` builds the scene, bakes Mantaflow once, adds the interpolation twin and saves the
baked .blend (skipped when it exists, so a resumed run reuses the bake). `render` opens that
file and renders every requested pass of every frame. They are two processes because a
Mantaflow solver left in memory by a bake can abort the process later ("can't clean grid
cache, some grids are still in use", seen mid-render on a 32-voxel bench scene), while a
process that loads the baked file reads the cache without one.
It talks to the parent through `@@` lines on stdout and ends with os._exit, because
a baked Mantaflow interpreter aborts at normal exit.
"""
from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from blender.job import JobError, WorkerJob, built_scene_path
from contracts.atomic import atomic_path, write_text
from contracts.dataset_format import has_frame


def emit(kind: str, **payload: Any) -> None:
    sys.stdout.write(f"@@{kind} {json.dumps(payload)}\n")
    sys.stdout.flush()


STAGES = ("bake", "render")


def _open_baked(job: WorkerJob):
    """The baked scene saved by the `bake` stage."""
    import bpy

    from blender import scene as scene_mod

    if not (Path(job.blend_path).exists() and built_scene_path(job.blend_path).exists()):
        raise RuntimeError(f"{job.blend_path}: no baked scene; run the bake stage first")
    bpy.ops.wm.open_mainfile(filepath=job.blend_path)
    built = scene_mod.BuiltScene.from_json(json.loads(built_scene_path(job.blend_path).read_text()))
    scene_mod.prepare_for_rendering(built)
    return built


def _bake(job: WorkerJob) -> None:
    """Build, bake, add the twin and save; the timings go into the summary for the render stage."""
    from blender import scene as scene_mod

    blend, built_path = Path(job.blend_path), built_scene_path(job.blend_path)
    if blend.exists() and built_path.exists():
        emit("stage", name="bake", status="reused")
        return
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    built = scene_mod.build(job)
    timings["build"] = time.perf_counter() - t0
    if built.domain:
        emit("stage", name="bake", status="start", frames=job.sim.frame_end)
        t0 = time.perf_counter()
        scene_mod.bake(built.domain)
        timings["bake"] = time.perf_counter() - t0
        emit("stage", name="bake", status="done", seconds=timings["bake"])
        scene_mod.add_interpolation_twin(built)
    import bpy

    with atomic_path(blend) as tmp:
        bpy.ops.wm.save_as_mainfile(filepath=str(tmp), compress=False)
    previous = _previous_summary(job)
    _save_summary(job, {**previous, "timings": {**previous["timings"], **timings}})
    write_text(built_path, json.dumps(built.to_json()))


def _previous_summary(job: WorkerJob) -> dict[str, Any]:
    """What an interrupted earlier run measured, so a resumed dataset still reports it."""
    path = Path(job.summary_path)
    return json.loads(path.read_text()) if path.exists() else {"timings": {}, "passes": {}}


def _render_all(job: WorkerJob, built) -> dict[str, Any]:
    from blender import render

    render.configure_engine(job.seed, job.threads)
    previous = _previous_summary(job)
    timings = previous["timings"]
    per_pass: dict[str, dict[str, float]] = {}
    for modality, passes in job.passes.items():
        camera = job.cameras[modality]
        render.select_modality(modality, built)
        for name in passes:
            setup = render.pass_setup(modality, name, camera)
            cam = camera.depth if name == "depth" else camera.render
            render.apply_pass(setup, built, cam)
            folder = Path(job.raw_dir) / modality / name
            folder.mkdir(parents=True, exist_ok=True)
            ext = "png" if setup.file_format == "PNG" else "exr"
            key = f"{modality}.{name}"
            frames = [f for f in camera.frames if has_frame(modality, name, f.split)]
            before = previous["passes"].get(key, {})
            done, seconds = before.get("rendered", 0), before.get("seconds", 0.0)
            for frame in frames:
                path = folder / f"{frame.stem}.{ext}"
                fresh = not path.exists()
                if fresh:
                    t0 = time.perf_counter()
                    render.show_smoke_state(built, setup.smoke_visible, frame.next_weight, job.density_scale)
                    render.render_to(str(path), frame.c2w, frame.blender_frame)
                    seconds += time.perf_counter() - t0
                    done += 1
                emit("progress", item=key, frame=frame.stem, total=len(frames), rendered=fresh)
            per_pass[key] = {"rendered": done, "seconds": seconds,
                             "seconds_per_frame": seconds / done if done else None}
            _save_summary(job, {**previous, "timings": {**previous["timings"], **timings},
                                "passes": {**previous["passes"], **per_pass}})
    return {"timings": {**previous["timings"], **timings}, "passes": per_pass}


def _save_summary(job: WorkerJob, summary: dict[str, Any]) -> None:
    write_text(Path(job.summary_path), json.dumps(summary, indent=2))


def main(argv: list[str]) -> None:
    if len(argv) != 3 or argv[2] not in STAGES:
        sys.stderr.write("usage: python -m blender.worker JOB.json {bake|render}\n")
        os._exit(2)
    try:
        job = WorkerJob.read(Path(argv[1]))
    except JobError as exc:
        emit("error", message=f"JobError: {exc}")
        os._exit(2)
    try:
        import bpy  # noqa: F401  (loads the manta module the repair patches)

        from blender.manta_repair import repair_manta_hierarchy

        relinked = repair_manta_hierarchy()
        emit("stage", name="manta_repair", relinked=relinked)
        if argv[2] == "bake":
            _bake(job)
        else:
            summary = _render_all(job, _open_baked(job))
            summary["grids"] = sorted(job.grids)
            summary["bpy"] = bpy.app.version_string
            _save_summary(job, summary)
        emit("done", stage=argv[2], summary=job.summary_path)
        code = 0
    except Exception as exc:  # the parent turns this into one clear line plus the log path
        traceback.print_exc()
        sys.stderr.flush()
        emit("error", message=f"{type(exc).__name__}: {exc}")
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    main(sys.argv)
