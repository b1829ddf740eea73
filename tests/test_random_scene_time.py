"""The drawn-scene timing (benchmarks/random_scene_time.py): it reads a finished scene's record back
and splits its time by pass from the dataset's own timings."""
from __future__ import annotations

import csv
import json
import shutil
import subprocess
from pathlib import Path

import pytest

from benchmarks import random_scene_time

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "data" / "random_dev" / "random_1000"


@pytest.mark.skipif(not SCENE.is_dir(), reason="needs the committed random-dev set")
def test_a_recorded_scene_is_read_back_and_split_by_pass(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    work = tmp_path / "work"
    shutil.copytree(SCENE, work / SCENE.name)
    record = {"seed": 1000, "wall_s": 180.0, "threads": 2, "load_before": 0.5, "load_after": 2.0}
    (work / SCENE.name / random_scene_time.RECORD).write_text(json.dumps(record))
    monkeypatch.setattr(subprocess, "run", lambda *a, **k: pytest.fail("a recorded scene was generated again"))
    out = tmp_path / "time.csv"
    random_scene_time.main(["1000", "--work", str(work), "--csv", str(out)])
    with out.open() as fh:
        (row,) = list(csv.DictReader(fh))
    meta = json.loads((SCENE / "dataset.json").read_text())
    rgb_frames = len(json.loads((SCENE / "transforms_rgb.json").read_text())["frames"])
    assert float(row["wall_s"]) == 180.0 and float(row["load_before"]) == 0.5
    shadowed = meta["timings_s"]["render"]["rgb.shadowed"] * rgb_frames
    assert float(row["rgb.shadowed_s"]) == pytest.approx(shadowed, abs=0.06)
    passes = sum(float(v) for k, v in row.items() if k.startswith(("rgb.", "thermal.")))
    worker = meta["timings_s"]["worker"]
    assert 0.8 * worker < passes < worker  # the renders are the worker's time, less the scene's load
    assert row["fire"] == str(bool(meta["smoke"]["fire"]))

    # A scene made under the test-view rule holds the shadowed frames of its test views alone.
    frames = json.loads((SCENE / "transforms_rgb.json").read_text())["frames"]
    for frame in frames:
        if frame["split"] != "test":
            (work / SCENE.name / "rgb" / "shadowed" / f"{frame['file_stem']}.png").unlink()
    tests = sum(frame["split"] == "test" for frame in frames)
    assert 0 < tests < rgb_frames
    assert random_scene_time.row(record, work)["rgb.shadowed_s"] == pytest.approx(
        meta["timings_s"]["render"]["rgb.shadowed"] * tests, abs=0.06)
