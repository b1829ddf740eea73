"""The clean-ceiling dataset of eval/clean_ceiling.py, read back by the trainer's own loader."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from contracts.results_format import ResultsFormatError
from eval.clean_ceiling import derive_clean_dataset, smoky_input_psnr
from scenes.load import load_scene
from tests.results_builder import write_metrics


def test_derived_dataset_trains_on_the_clean_frames(demo_dataset: Path, tmp_path: Path) -> None:
    original = load_scene(demo_dataset, all_ground_truth=True)
    derived = load_scene(derive_clean_dataset(demo_dataset, tmp_path / "ceiling"), all_ground_truth=True)
    assert original.rgb.masks is not None and (original.rgb.masks > 0).any()
    assert not np.array_equal(original.rgb.images, original.rgb.clean)  # the demo has smoke to remove
    np.testing.assert_array_equal(derived.rgb.images, original.rgb.clean)
    np.testing.assert_array_equal(derived.rgb.clean, original.rgb.clean)
    assert derived.rgb.masks is None and not derived.smoke_present
    np.testing.assert_array_equal(derived.thermal.images, original.thermal.images)
    note = json.loads((tmp_path / "ceiling" / "dataset.json").read_text())["derived_from"]
    assert note["dataset"] == str(demo_dataset.resolve()) and "clean" in note["change"]
    assert not list(tmp_path.glob(".*staging"))


def test_a_dataset_without_clean_frames_is_refused(demo_dataset: Path, tmp_path: Path) -> None:
    copy = tmp_path / "no_clean"
    shutil.copytree(demo_dataset, copy)
    meta = json.loads((copy / "dataset.json").read_text())
    meta["passes"]["rgb"].remove("clean")
    (copy / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"dataset\.json: field 'passes\.rgb' has no 'clean'"):
        derive_clean_dataset(copy, tmp_path / "ceiling")
    assert not (tmp_path / "ceiling").exists()


def test_smoky_input_psnr_reads_a_finished_run_of_the_profile(tmp_path: Path) -> None:
    def run(method: str, profile: str, status: str, psnr_input: float) -> None:
        write_metrics(tmp_path / "house" / method / "seed0-abc", scene="house", method=method, profile=profile,
                      seed=0, status=status, metrics={"psnr_input": psnr_input},
                      **({"validation": {"psnr_input": psnr_input - 1}} if status == "ok" else {}))

    assert smoky_input_psnr("house", "standard", tmp_path) == (None, None)
    run("full", "quick", "ok", 20.0)
    run("no-mask", "standard", "failed", 25.0)
    assert smoky_input_psnr("house", "standard", tmp_path) == (None, None)
    run("rgb-only", "standard", "ok", 31.0)
    assert smoky_input_psnr("house", "standard", tmp_path) == (31.0, 30.0)
    (tmp_path / "house" / "full" / "seed0-abc" / "metrics.json").write_text(json.dumps({"profile": "standard"}))
    with pytest.raises(ResultsFormatError, match=r"full/seed0-abc/metrics\.json: missing field 'format'"):
        smoky_input_psnr("house", "standard", tmp_path)
