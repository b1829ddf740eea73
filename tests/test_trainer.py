"""End-to-end `train-and-evaluate` at tiny budgets: outputs, resume, NaN handling, edge scenes.

The scenes come from `write_splat_dataset` (bpy-free, see test_smokeseer_data.py), except the
demo test, which uses the real generator through the `demo_dataset` fixture.
"""
from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import pytest
import torch

from smokeseer.cli import main
from smokeseer.raster import read_ply
from contracts.results_format import validate_run_dir
from tests.test_smokeseer_data import write_splat_dataset

TINY = ["--iterations-stage2", "12", "--iterations-stage3", "12", "--no-progress",
        "--set", "stage2.init_points=300", "--set", "stage3.smoke_points=120",
        "--set", "log_every=3", "--set", "stage3.test_every=6", "--set", "checkpoint_every=6",
        "--set", "deform.warmup_iterations=3"]


def _log_rows(run: Path) -> list[dict[str, str]]:
    with (run / "train_log.csv").open() as fh:
        return list(csv.DictReader(fh))


def _assert_complete(run: Path, thermal: bool = True) -> dict:
    doc = validate_run_dir(run)
    assert doc["status"] == "ok"
    stems = [e["file_stem"] for e in doc["per_image"]]
    assert stems
    for sub in ("composite", "surface", "smoke") + (("thermal",) if thermal else ()):
        assert sorted(p.stem for p in (run / "renders" / sub).glob("*.png")) == sorted(stems)
    for key in ("psnr", "ssim", "psnr_input", "depth_absrel", "depth_rmse"):
        assert math.isfinite(doc["metrics"][key])
    ply = read_ply(run / "ply" / "surface.ply")
    assert ply.means.shape[0] == doc["stages"]["surface_gaussians"]
    rows = _log_rows(run)
    assert {r["stage"] for r in rows} >= {"3"} and any(r["test_psnr"] for r in rows)
    return doc


@pytest.fixture(scope="module")
def splat(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_splat_dataset(tmp_path_factory.mktemp("tr") / "moving", n_rgb=8, n_thermal=6)


@pytest.mark.slow
def test_demo_dataset_end_to_end(demo_dataset: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    assert main([str(demo_dataset), "--mode", "full", "--out", str(run)] + TINY) == 0
    doc = _assert_complete(run)
    assert len(list((run / "ply").glob("smoke_t*.ply"))) == 3
    assert doc["scene"] == "demo" and doc["method"] == "full"


def test_full_run_outputs_and_resume(splat: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run)] + TINY) == 0
    doc = _assert_complete(run)
    assert doc["stages"]["smoke_gaussians"] > 0 and doc["metrics"]["mask_iou"] is not None
    n_rows = len(_log_rows(run))
    # A finished run reruns without training again and gives the same scores.
    assert main([str(splat), "--out", str(run)] + TINY) == 0
    again = json.loads((run / "metrics.json").read_text())
    assert again["metrics"]["psnr"] == pytest.approx(doc["metrics"]["psnr"], abs=1e-9)
    assert len(_log_rows(run)) == n_rows
    # An interrupted Stage 3 continues from its checkpoint instead of starting over.
    ck = torch.load(run / "checkpoints" / "stage3.pt", weights_only=False)
    assert ck["done"] and ck["iteration"] == 12
    ck["done"], ck["iteration"] = False, 6
    torch.save(ck, run / "checkpoints" / "stage3.pt")
    assert main([str(splat), "--out", str(run)] + TINY) == 0
    new_rows = _log_rows(run)[n_rows:]
    assert [int(r["iteration"]) for r in new_rows if r["stage"] == "3"] == [9, 12]
    assert not [r for r in new_rows if r["stage"] == "2"]
    # A different Stage 3 setting (an ablation) reuses the finished Stage 2 and redoes Stage 3.
    n_rows = len(_log_rows(run))
    assert main([str(splat), "--out", str(run), "--mode", "no-smoke-color"] + TINY) == 0
    new_rows = _log_rows(run)[n_rows:]
    assert {r["stage"] for r in new_rows} == {"3"} and int(new_rows[0]["iteration"]) == 3


def test_same_seed_gives_the_same_model(splat: Path, tmp_path: Path) -> None:
    """Seeds make a run reproducible: the same seed gives the same PLY bytes, another seed does not."""
    plys = {}
    for name, seed in (("a", "3"), ("b", "3"), ("c", "4")):
        assert main([str(splat), "--out", str(tmp_path / name), "--seed", seed] + TINY) == 0
        plys[name] = (tmp_path / name / "ply" / "surface.ply").read_bytes()
    assert plys["a"] == plys["b"]
    assert plys["a"] != plys["c"]


@pytest.mark.parametrize("mode", ["rgb-only", "deformable-3dgs", "no-mask"])
def test_other_modes_run(splat: Path, tmp_path: Path, mode: str) -> None:
    run = tmp_path / mode
    assert main([str(splat), "--mode", mode, "--out", str(run)] + TINY) == 0
    doc = validate_run_dir(run)
    assert doc["method"] == mode and math.isfinite(doc["metrics"]["psnr"])
    if mode == "deformable-3dgs":
        assert doc["stages"]["smoke_gaussians"] == 0 and doc["metrics"]["mask_iou"] is None
        assert doc["stages"]["geometry_modality"] == "rgb"
    if mode == "rgb-only":
        assert doc["stages"]["geometry_modality"] == "rgb"
        assert not (run / "renders" / "thermal").exists()


@pytest.mark.parametrize("smoke", ["none", "opaque"])
def test_no_smoke_and_opaque_smoke_train_without_nan(tmp_path: Path, smoke: str) -> None:
    # The opaque scene is also flagged static: that must drop the deformation network.
    ds = write_splat_dataset(tmp_path / smoke, smoke=smoke, n_rgb=8, n_thermal=6, static_flag=smoke == "opaque")
    run = tmp_path / f"run-{smoke}"
    assert main([str(ds), "--out", str(run)] + TINY) == 0
    doc = validate_run_dir(run)
    assert doc["status"] == "ok"
    if smoke == "none":
        assert doc["stages"]["smoke_gaussians"] == 0 and doc["metrics"]["mask_iou"] is None
    else:
        assert doc["stages"]["smoke_gaussians"] > 0 and doc["stages"]["deformation"] is False
        assert torch.load(run / "checkpoints" / "stage3.pt", weights_only=False)["deform"] is None
    for row in _log_rows(run):
        assert math.isfinite(float(row["loss"]))


def test_divergence_is_reported_with_checkpoint(splat: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    run = tmp_path / "nan"
    # A huge scale learning rate blows Gaussians up to infinite size after one step.
    rc = main([str(splat), "--out", str(run), "--set", "lr.scales=1e5"] + TINY)
    assert rc == 1
    err = capsys.readouterr().err
    found = re.search(r"diverged: non-finite value in (\S+) at stage 2, iteration (\d+)", err)
    assert found and found.group(1).startswith("gaussians."), err
    # The saved state is the last good one: the iteration before the one that failed.
    nan_ck = torch.load(run / "checkpoints" / "stage2_nan.pt", weights_only=False)
    assert nan_ck["iteration"] in (int(found.group(2)) - 1, int(found.group(2)))
    doc = validate_run_dir(run)
    assert doc["status"] == "failed" and "NaNDetected" in doc["error"] and "metrics" not in doc
    assert (run / "checkpoints" / "stage2_nan.pt").is_file()


def test_bad_input_gives_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main([str(tmp_path / "nowhere"), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nowhere" in err[0] and err[0].startswith("train-and-evaluate: error:")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "dataset.json").write_text(json.dumps({"format": "smokeseer-synth-dataset", "passes": {"rgb": ["smoky"]}}))
    assert main([str(bad), "--out", str(tmp_path / "r2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "transforms_rgb.json: missing file" in err[0]
    assert main([str(bad), "--out", str(tmp_path / "r3"), "--set", "nope=1"]) == 2
    assert "overrides: unknown key 'nope'" in capsys.readouterr().err
    assert main([str(bad), "--out", str(tmp_path / "r4"), "--set", "depth_prior=mono",
                 "--set", "mono_weights=/nonexistent/depth.pt"]) == 2
    assert "mono_weights: no TorchScript file" in capsys.readouterr().err
