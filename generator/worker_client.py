"""Runs the Blender worker in a subprocess, turns its `@@` lines into progress bars and
log lines, and turns a crash into one error that names the log file."""
from __future__ import annotations

import json
import logging
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, TextIO

from tqdm import tqdm

from blender.job import WorkerJob
from generator.errors import WorkerError

log = logging.getLogger("generate-scene")

#: What Mantaflow prints when it aborts while freeing a solver that reads the bake's cache.
#: It happens now and then between renders (seen after 3 and after 73 images of a bench
#: scene); every finished image is already in place, so the render stage resumes.
MANTA_CLEANUP_ABORT = "can't clean grid cache, some grids are still in use"
MAX_RENDER_RESTARTS = 3


class MantaCleanupAbort(Exception):
    """The render worker died of Mantaflow's cache-cleanup abort (SIGABRT)."""


def run_worker(job: WorkerJob, work: Path, show_progress: bool = True,
               before_render: Callable[[WorkerJob], WorkerJob] | None = None) -> dict[str, Any]:
    """Bake, then render, each in its own worker process (see blender/worker.py for why).
    `before_render` may change the job's render-only fields once the bake exists (the smoke's
    calibration, generator.optical_depth)."""
    job_path = work / "job.json"
    job.write(job_path)
    log_path = work / "logs" / "worker.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    bars: dict[str, tqdm] = {}
    counts = {True: 0, False: 0}
    started = time.perf_counter()
    _run_stage(job_path, "bake", log_path, bars, counts, show_progress)
    if before_render is not None:
        job = before_render(job)
        job.write(job_path)
    restarts = _render_stage(job_path, log_path, bars, counts, show_progress)
    for bar in bars.values():
        bar.close()
    log.info("rendered %d images, reused %d from an earlier run", counts[True], counts[False])
    summary = json.loads(Path(job.summary_path).read_text())
    summary["wall_s"] = time.perf_counter() - started
    summary["render_restarts"] = restarts
    return summary


def render_baked(job: WorkerJob, job_path: Path, log_path: Path, show_progress: bool = True) -> int:
    """Only the render stage of `job`, whose bake already exists; returns the restarts."""
    job.write(job_path)
    bars: dict[str, tqdm] = {}
    restarts = _render_stage(job_path, log_path, bars, {True: 0, False: 0}, show_progress)
    for bar in bars.values():
        bar.close()
    return restarts


def _render_stage(job_path: Path, log_path: Path, bars: dict[str, tqdm], counts: dict[bool, int],
                  show_progress: bool) -> int:
    restarts = 0
    while True:
        try:
            _run_stage(job_path, "render", log_path, bars, counts, show_progress)
            return restarts
        except MantaCleanupAbort:
            restarts += 1
            if restarts > MAX_RENDER_RESTARTS:
                raise WorkerError(f"Blender worker failed (render): Mantaflow aborted in its cache cleanup "
                                  f"{restarts} times. Full log: {log_path}") from None
            log.warning("the render worker aborted in Mantaflow's cache cleanup (a pip-bpy defect, "
                        "docs/generator.md); resuming from the finished images (restart %d of %d)",
                        restarts, MAX_RENDER_RESTARTS)


def _run_stage(job_path: Path, stage: str, log_path: Path, bars: dict[str, tqdm], counts: dict[bool, int],
               show_progress: bool) -> None:
    repo_root = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, "-m", "blender.worker", str(job_path), stage]
    with log_path.open("a") as log_file:
        log_file.write(f"\n=== worker started: {' '.join(cmd)}\n")
        log_file.flush()
        proc = subprocess.Popen(cmd, cwd=repo_root, stdout=subprocess.PIPE, stderr=log_file, text=True, bufsize=1)
        try:
            error = _follow(proc, log_file, bars, counts, show_progress)
        except BaseException:  # Ctrl-C or SIGTERM: stop the worker too; finished images stay for a resume
            proc.terminate()
            proc.wait()
            raise
        code = proc.wait()
    if code == -signal.SIGABRT and stage == "render" and MANTA_CLEANUP_ABORT in _tail(log_path):
        raise MantaCleanupAbort()
    if code != 0:
        reason = error or f"exited with code {code}"
        raise WorkerError(f"Blender worker failed ({stage}): {reason}. Full log: {log_path}")


def _tail(path: Path, size: int = 4096) -> str:
    with path.open("rb") as fh:
        fh.seek(max(0, path.stat().st_size - size))
        return fh.read().decode(errors="replace")


def _follow(proc: subprocess.Popen, log_file: TextIO, bars: dict[str, tqdm], counts: dict[bool, int],
            show_progress: bool) -> str | None:
    """Copy the worker's stdout to its log and act on its `@@` lines; returns its error message."""
    assert proc.stdout is not None
    error: str | None = None
    for line in proc.stdout:
        log_file.write(line)
        if not line.startswith("@@"):
            continue
        kind, _, payload = line[2:].partition(" ")
        data = json.loads(payload)
        if kind == "progress":
            bar = bars.get(data["item"])
            if bar is None:
                bar = bars[data["item"]] = tqdm(total=data["total"], desc=f"render {data['item']}",
                                                 unit="frame", disable=not show_progress, leave=False)
            bar.update(1)
            counts[data["rendered"]] += 1
            if bar.n >= bar.total:
                bar.close()
        elif kind == "stage" and data.get("status") in ("done", "reused"):
            seconds = data.get("seconds")
            log.info("%s %s%s", data["name"], data["status"], f" in {seconds:.1f} s" if seconds else "")
        elif kind == "error":
            error = data["message"]
    return error
