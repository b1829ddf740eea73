"""The depth term compares at the thermal camera (the paper), or at the RGB camera when asked
or when a run has no thermal input, and says which in the log and metrics.json."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from smokeseer.api import prepare
from smokeseer.cli import main
from smokeseer.config import make_config
from smokeseer.train.plan import depth_camera, depth_term_on
from tests.test_smokeseer_data import write_splat_dataset
from tests.test_trainer import TINY


@pytest.fixture(scope="module")
def splat(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_splat_dataset(tmp_path_factory.mktemp("dc") / "moving", n_rgb=8, n_thermal=6)


def _depth_losses(run: Path) -> list[float]:
    with (run / "train_log.csv").open() as fh:
        return [float(r["depth"]) for r in csv.DictReader(fh) if r["stage"] == "3" and r["depth"]]


@pytest.mark.parametrize("camera", ["thermal", "rgb"])
def test_depth_term_runs_at_the_chosen_camera(splat: Path, tmp_path: Path, camera: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / camera
    assert main([str(splat), "--out", str(run), "--set", f"depth_camera={camera}"] + TINY) == 0
    assert f"depth term at the {camera} camera" in capsys.readouterr().err
    losses = _depth_losses(run)
    assert losses and all(v >= 0.0 for v in losses)


def test_rgb_only_has_no_thermal_camera_and_says_so(splat: Path, tmp_path: Path) -> None:
    prep = prepare(splat, mode="rgb-only", overrides={"depth_camera": "thermal"})
    assert depth_camera(prep.cfg, prep.plan.use_thermal) == "rgb" and prep.plan.depth_camera == "rgb"
    run = tmp_path / "rgb-only"
    assert main([str(splat), "--mode", "rgb-only", "--out", str(run), "--set", "depth_camera=thermal"] + TINY) == 0
    stages = json.loads((run / "metrics.json").read_text())["stages"]
    assert any("depth term at the rgb camera, not thermal" in n for n in stages["notes"])
    assert stages["stage3_plan"]["depth_camera"] == "rgb" and stages["stage3_plan"]["loss_weights"]["depth"] > 0


def test_unknown_camera_is_refused(splat: Path) -> None:
    with pytest.raises(ValueError, match="depth_camera"):
        prepare(splat, overrides={"depth_camera": "lidar"})


def test_which_runs_have_a_depth_term() -> None:
    """With loss.depth=0 the prior is not rendered and the log does not announce a depth term; the
    standard profile has none unless a prior is named (docs/method.md), the quick profile has one."""
    assert depth_term_on(make_config("full", "quick"))
    assert not depth_term_on(make_config("full", "quick", overrides={"loss.depth": 0.0}))
    assert not depth_term_on(make_config("no-depth", "quick"))
    assert not depth_term_on(make_config("full", "standard"))
    assert depth_term_on(make_config("full", "standard", overrides={"depth_prior": "thermal-render"}))
