"""The drawn sets' report (benchmarks/random_sets.py): rows, spans, figures, and its refusals."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from benchmarks.random_sets import main

pytestmark = pytest.mark.blender


def _scene(seed: int, tau: float, seconds: float, fire: bool) -> dict:
    return {"scene": f"random_{seed}", "seed": seed, "status": "generated", "seconds": seconds, "objects": 4,
            "sources": 1, "fire": fire, "particles": "soot" if fire else "organic_smoke", "trajectory": "orbit",
            "wind": 1.0, "thermal_size": [32, 24], "optical_depth_target": tau, "optical_depth_achieved": tau,
            "stats": {"test_views": {"rgb_optical_depth": tau / 2, "unrecoverable_share": tau / 10},
                      "thermal_contrast": {"contrast_k": 30.0 + seed % 7}}}


def _set(root: Path, demo: Path, scenes: list[dict]) -> Path:
    for s in scenes:
        shutil.copytree(demo, root / s["scene"])
    (root / "benchmark.json").write_text(json.dumps({"kind": "random", "scenes": scenes[::-1]}))
    return root


def test_the_report_lists_every_scene_and_states_the_spans(demo_dataset: Path, tmp_path: Path) -> None:
    dev = _set(tmp_path / "random_dev", demo_dataset, [_scene(1000, 0.12, 170.0, True), _scene(1001, 2.6, 190.0, False),
                                                       _scene(1002, 1.0, 150.0, False)])
    out = tmp_path / "report"
    assert main([str(dev), "--out", str(out)]) == 0
    with open(out / "random_dev_scenes.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["seed"] for r in rows] == ["1000", "1001", "1002"]  # seed order, whatever the record's
    assert rows[1]["test_rgb_optical_depth"] == "1.3" and rows[1]["contrast_k"] == "30.0"
    text = (out / "summary.md").read_text()
    assert "0.120-2.600; 2 of 3 scenes (67 %) at 1 or more" in text and "median 170 s a scene (150-190 s)" in text
    assert "1 scenes with fire, 1 with soot, 2 with organic smoke" in text
    sheet = np.asarray(Image.open(out / "random_dev_contact_sheet.png").convert("RGB"), dtype=float)
    assert sheet.std() > 20.0  # frames, not blank tiles
    assert (out / "axes.png").is_file()


def test_a_set_that_is_not_drawn_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "standard").mkdir()
    (tmp_path / "standard" / "benchmark.json").write_text(json.dumps({"profile": "standard", "scenes": []}))
    assert main([str(tmp_path / "standard"), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"random_sets: error: {tmp_path / 'standard' / 'benchmark.json'}: kind: not a drawn set "
        "(generate-benchmark --random)"]
    assert main([str(tmp_path / "missing"), "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()
