"""The generator → Blender worker contract (blender/job.py): typed, serialised, validated on both sides."""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from blender.job import JobError, WorkerJob
from generator.api import resolve_spec
from generator.assets import load_manifest
from generator.job import make_job, make_plan, resolve_asset_materials

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def demo_job(tmp_path_factory: pytest.TempPathFactory) -> WorkerJob:
    spec, source = resolve_spec("demo")
    manifest = load_manifest()
    spec = resolve_asset_materials(spec, manifest, source)
    return make_job(spec, make_plan(spec), manifest, source, tmp_path_factory.mktemp("work"), 1)


def test_job_round_trips_through_json(demo_job: WorkerJob, tmp_path: Path) -> None:
    path = tmp_path / "job.json"
    demo_job.write(path)
    assert WorkerJob.read(path) == demo_job
    assert not list(tmp_path.glob(".*.tmp")), "written atomically"
    thermal = demo_job.cameras["thermal"]
    assert any(0 < f.next_weight < 1 for f in thermal.frames)


def _corrupt(job: WorkerJob, tmp_path: Path, edit) -> Path:
    data = job.to_data()
    edit(data)
    path = tmp_path / "job.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("edit, needle", [
    (lambda d: d["cameras"]["rgb"]["frames"][0].update(next_weight="half"),
     "cameras.rgb.frames[0].next_weight: must be a finite number, got 'half'"),
    (lambda d: d["cameras"]["thermal"]["frames"][1].update(next_weight=1.5),
     "cameras.thermal.frames[1].next_weight: must lie in [0, 1)"),
    (lambda d: d["cameras"]["rgb"].update(denoise="magic"), "cameras.rgb.denoise: must be one of none, color"),
    (lambda d: d["objects"][1].update(material="marble"), "objects[1].material: unknown material 'marble'"),
    (lambda d: d["sim"].pop("fps"), "sim.fps: missing"),
    (lambda d: d["world"].update(sun_colour=[1, 1, 1]), "world.sun_colour: unknown field"),
    (lambda d: d["passes"].update(rgb=["smoky", "glossy"]), "passes.rgb: unknown pass 'glossy'"),
])
def test_bad_jobs_name_the_file_and_field(demo_job: WorkerJob, tmp_path: Path, edit, needle: str) -> None:
    path = _corrupt(demo_job, tmp_path, edit)
    with pytest.raises(JobError) as info:
        WorkerJob.read(path)
    assert str(info.value) == f"{path}: {needle}" or str(info.value).startswith(f"{path}: {needle}")


def test_the_writer_refuses_an_invalid_job(demo_job: WorkerJob, tmp_path: Path) -> None:
    cam = demo_job.cameras["rgb"]
    for bad_cam in (replace(cam, samples=0), replace(cam, clean_samples=0)):
        bad = replace(demo_job, cameras={**demo_job.cameras, "rgb": bad_cam})
        with pytest.raises(JobError, match="cameras.rgb: samples, clean_samples and volume_step_rate must be positive"):
            bad.write(tmp_path / "job.json")
        assert not (tmp_path / "job.json").exists()
    with pytest.raises(JobError, match="density_scale: must not be negative"):
        replace(demo_job, density_scale=-0.5).write(tmp_path / "job.json")


@pytest.mark.blender
def test_worker_reports_a_bad_job_as_one_line(demo_job: WorkerJob, tmp_path: Path) -> None:
    path = _corrupt(demo_job, tmp_path, lambda d: d["sim"].update(resolution="high"))
    result = subprocess.run([sys.executable, "-m", "blender.worker", str(path), "render"], cwd=REPO, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 2
    errors = [line for line in result.stdout.splitlines() if line.startswith("@@error ")]
    assert len(errors) == 1
    assert json.loads(errors[0][len("@@error "):])["message"] == \
        f"JobError: {path}: sim.resolution: must be an integer, got 'high'"
