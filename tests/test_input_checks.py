"""The trainer says when its input or its optimisation makes no sense: the input checks' statistics
on analytic cases, the divergence watch, and end to end on the tiny bench dataset (degenerate
copies of it) the warnings, the flat-thermal fallback, the diverged status and the refusals.

Well-formed tiny runs raising no warning is checked by every complete run of tests/test_trainer.py
(``_assert_complete``)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from contracts.folder_lock import folder_lock, lock_held, lock_path, refuse_if_busy
from contracts.results_format import validate_run_dir
from scenes.cameras import SceneBounds, c2w_gl_to_viewmat
from scenes.scene import Frame, ModalityData
from smokeseer.cli import main
from smokeseer.stage1.input_checks import MIN_CONTRAST, clipped_share, contrast, frame_contrast, parallax
from smokeseer.train.divergence import LossWatch, StageDiverged
from tests.test_smokeseer_data import _look_at_c2w_gl, write_splat_dataset
from tests.test_trainer import TINY

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def splat(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_splat_dataset(tmp_path_factory.mktemp("checks") / "moving", n_rgb=8, n_thermal=6)


def _degenerate(splat: Path, dst: Path, folder: str, value: int) -> Path:
    """A copy of ``splat`` whose every ``folder`` PNG holds ``value`` everywhere."""
    shutil.copytree(splat, dst)
    for png in (dst / folder).glob("*.png"):
        img = np.asarray(Image.open(png))
        Image.fromarray(np.full_like(img, value)).save(png)
    return dst


def _run(data: Path, out: Path, capsys: pytest.CaptureFixture, *extra: str) -> tuple[int, dict, str]:
    rc = main([str(data), "--out", str(out)] + TINY + list(extra))
    err = capsys.readouterr().err
    return rc, json.loads((out / "metrics.json").read_text()), err


# ---------------------------------------------------------------- statistics on analytic cases


def test_clipped_share_counts_the_8bit_ends() -> None:
    img = np.array([0.0, 0.5 / 255, 0.6 / 255, 0.5, 254.4 / 255, 254.6 / 255, 1.0, 0.99])
    assert clipped_share(img) == 4 / 8


def test_contrast_is_zero_for_a_constant_frame_about_five_for_noise_and_large_for_a_scene() -> None:
    rng = np.random.default_rng(0)
    assert frame_contrast(np.full((60, 80), 0.7)) == 0.0
    # Gaussian noise: 99 % of it spans 5.15 σ, and the neighbour estimate finds σ (plus one level)
    noise = 0.5 + 0.1 * rng.standard_normal((200, 200))
    assert frame_contrast(noise) == pytest.approx(5.15 * 0.1 / (0.1 + 1 / 255), rel=0.05)
    # a noise-free step from 0.2 to 0.8: spread 0.6 over one level
    step = np.where(np.arange(80) < 40, 0.2, 0.8)[None, :].repeat(60, 0)
    assert frame_contrast(step) == pytest.approx(0.6 * 255)
    # the median over frames, channels averaged
    frames = np.stack([np.full((60, 80, 3), 0.3), step[..., None].repeat(3, -1), step[..., None].repeat(3, -1)])
    assert contrast(frames) == pytest.approx(0.6 * 255)
    assert contrast(noise[None, ..., None]) < MIN_CONTRAST < contrast(frames)


def _cameras(centres: list[np.ndarray], target: np.ndarray) -> ModalityData:
    k = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])
    frames = [Frame(f"{i:04d}", c2w_gl_to_viewmat(_look_at_c2w_gl(c, target)), k, 64, 48, 0.0, 0.0, "train")
              for i, c in enumerate(centres)]
    return ModalityData("rgb", frames, np.zeros((len(frames), 48, 64, 3), np.float32))


def test_parallax_is_the_baseline_over_the_distance_to_the_scene() -> None:
    """Two cameras 3 from the scene centre, 90° apart: diameter 3√2 over mean distance 3 = √2;
    the same camera twice: 0."""
    target = np.zeros(3)
    bounds = SceneBounds(center=target, half_size=1.0, extent=3.0)
    apart = _cameras([np.array([3.0, 0, 0]), np.array([0, 3.0, 0])], target)
    assert parallax(apart, bounds) == pytest.approx(np.sqrt(2.0))
    assert parallax(_cameras([np.array([3.0, 0, 0])] * 2, target), bounds) == 0.0


# ---------------------------------------------------------------- the divergence watch


def test_loss_watch_ignores_view_to_view_spread_and_stops_a_runaway_loss() -> None:
    """Views whose losses differ tenfold, alternating, never trip the watch: the first (low) one is
    the best, and the average settles at 5.5 times it, as (0.01 + 0.1) / 2 / 0.01 says. A loss
    that jumps after that trips it at the iteration its average passes 20× the best, and the error
    names the stage, the iteration and the best."""
    watch = LossWatch(factor=20.0, span=20)
    for it in range(1, 401):
        watch.update(3, "stage3", it, 0.01 if it % 2 else 0.1)
    assert watch.best == 0.01 and watch.max_rise == pytest.approx(5.5, rel=0.05)
    with pytest.raises(StageDiverged) as exc:
        for it in range(401, 501):
            watch.update(3, "stage3", it, 0.5)
    jump = exc.value
    # from a = 0.0573 (the average just after a 0.1 view), k steps of 0.5 give 0.5 - (0.5 - a) β^k with
    # β = 1 - 2/21; it passes 20 × 0.01 when β^k < 0.3 / 0.4427, at k = 4
    assert (jump.iteration, jump.best, jump.best_iteration) == (404, 0.01, 1) and jump.rise > 20
    assert str(jump).startswith(f"stage 3 loss (smoothed over 20 iterations) rose to {jump.loss:.4g} at iteration "
                                f"{jump.iteration}, ")
    assert "its best 0.01 (iteration 1; loss.divergence_factor=20)" in str(jump)
    # an opacity reset raises the loss on purpose: the watch starts over and keeps its largest rise
    watch.restart()
    for it in range(501, 601):
        watch.update(2, "stage2", it, 0.5)
    assert watch.best == pytest.approx(0.5) and watch.max_rise == jump.rise


# ---------------------------------------------------------------- end to end, tiny


def test_saturated_rgb_is_said_in_the_log_and_metrics(splat: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture) -> None:
    data = _degenerate(splat, tmp_path / "white", "rgb/smoky", 255)
    rc, doc, err = _run(data, tmp_path / "run", capsys)
    assert rc == 0 and doc["status"] == "ok"
    found = {w["code"]: w for w in doc["warnings"]}
    assert set(found) == {"rgb-saturated", "rgb-constant"}   # white everywhere is also no contrast
    assert found["rgb-saturated"]["value"] == 1.0 and found["rgb-saturated"]["statistic"] == "clipped_share"
    assert found["rgb-constant"]["value"] == 0.0
    assert ("[train-and-evaluate] warning rgb-saturated: 100 % of the training RGB values are clipped at 0 or 1 "
            "(warned from 50 %)") in err


def test_constant_rgb_is_said_in_the_log_and_metrics(splat: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    data = _degenerate(splat, tmp_path / "grey", "rgb/smoky", 128)
    rc, doc, err = _run(data, tmp_path / "run", capsys)
    assert rc == 0 and [w["code"] for w in doc["warnings"]] == ["rgb-constant"]
    assert doc["warnings"][0]["value"] == 0.0 and doc["warnings"][0]["limit"] == MIN_CONTRAST
    assert "[train-and-evaluate] warning rgb-constant: the training RGB frames carry no contrast" in err


def test_flat_thermal_trains_full_as_rgb_only_and_says_so(splat: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture) -> None:
    """Thermal frames without contrast teach Stage 2 no geometry: Full trains exactly as RGB-only
    does (the same model bytes and scores), keeps its method name, and says why in the log, the
    warnings and stages.thermal_used / thermal_dropped."""
    data = _degenerate(splat, tmp_path / "flat", "thermal/smoky", 3000)
    rc, doc, err = _run(data, tmp_path / "full", capsys)
    assert rc == 0 and doc["method"] == "full"
    assert [w["code"] for w in doc["warnings"]] == ["thermal-flat"] and doc["warnings"][0]["value"] == 0.0
    assert doc["stages"]["thermal_used"] is False and doc["stages"]["geometry_modality"] == "rgb"
    assert "so this run trains without thermal, as RGB-only does" in doc["stages"]["thermal_dropped"]
    assert "[train-and-evaluate] warning thermal-flat: the thermal frames carry no contrast" in err
    assert not (tmp_path / "full" / "renders" / "thermal").exists()
    rc, rgb_only, _ = _run(data, tmp_path / "rgb-only", capsys, "--mode", "rgb-only")
    assert rc == 0 and rgb_only["warnings"] == [] and rgb_only["stages"]["thermal_dropped"] == "rgb-only reads no thermal"
    assert rgb_only["metrics"] == doc["metrics"]
    for ply in ("surface.ply", "smoke_t0.50.ply"):
        assert (tmp_path / "full" / "ply" / ply).read_bytes() == (tmp_path / "rgb-only" / "ply" / ply).read_bytes()


def test_identical_poses_warn_that_there_is_no_parallax(splat: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture) -> None:
    data = tmp_path / "still"
    shutil.copytree(splat, data)
    for modality in ("rgb", "thermal"):
        path = data / f"transforms_{modality}.json"
        doc = json.loads(path.read_text())
        for frame in doc["frames"]:
            frame["transform_matrix"] = doc["frames"][0]["transform_matrix"]
        path.write_text(json.dumps(doc))
    rc, doc, err = _run(data, tmp_path / "run", capsys)
    assert rc == 0 and [w["code"] for w in doc["warnings"]] == ["no-parallax"]
    assert doc["warnings"][0]["value"] == 0.0
    assert "[train-and-evaluate] warning no-parallax: the training rgb and thermal cameras lie within 0 %" in err


def test_runaway_loss_stops_as_diverged_with_no_scores(splat: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture) -> None:
    """A smoke colour rate of 1e6 sends the Stage 3 loss from about 1 to thousands in one step: the
    stage stops there, the CLI says so in one line and exits 1, and metrics.json says diverged with
    where, and carries no scores, renders or PLYs."""
    run = tmp_path / "run"
    rc = main([str(splat), "--out", str(run), "--set", "lr.sh_dc=1e6"] + TINY)
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("train-and-evaluate:")]
    assert len(lines) == 1 and lines[0].startswith("train-and-evaluate: diverged: stage 3 loss (smoothed over 100 "
                                                   "iterations) rose to")
    doc = validate_run_dir(run)
    assert doc["status"] == "diverged" and "metrics" not in doc and "per_image" not in doc
    assert doc["diverged"]["stage"] == 3 and doc["diverged"]["iteration"] == 2 and doc["diverged"]["rise"] > 10
    assert [w["code"] for w in doc["warnings"]] == ["loss-diverged"]
    assert not any((run / d).exists() for d in ("ply", "renders", "figures"))


@pytest.mark.parametrize("setting, says", [
    ("stage3.iterations=0", "stage3.iterations: must be at least 1, got 0"),
    ("stage2.iterations=0", "stage2.iterations: must be at least 1, got 0"),
    ("lr.opacity=0", "lr.opacity: must be a positive finite number, got 0.0"),
    ("lr.means_init=-1e-4", "lr.means_init: must be a positive finite number, got -0.0001"),
    ("loss.render=0", "loss.render: must be a positive finite number, got 0.0"),
    ("stage2.init_points=0", "stage2.init_points: must be at least 1, got 0"),
    ("loss.mono=-1", "loss.mono: must be a finite weight >= 0, got -1.0"),
    ("loss.divergence_factor=1", "loss.divergence_factor: must exceed 1, got 1.0"),
    ("log_every=0", "log_every: must be at least 1, got 0"),
    ("stage3.smoke_densify.max_gaussians=0", "stage3.smoke_densify: every must be >= 0, max_gaussians at least 1"),
])
def test_settings_that_cannot_train_are_refused_with_nothing_written(splat: Path, tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture,
                                                                     setting: str, says: str) -> None:
    out = tmp_path / "run"
    assert main([str(splat), "--out", str(out)] + TINY + ["--set", setting]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"train-and-evaluate: error: {says}"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_run_folder_in_use_is_refused_with_nothing_written(splat: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture) -> None:
    """Another process holding the run folder's lock (as a training run does, and the harness for
    its runs): the second run is one line naming the holder, exit 2, nothing written; the lock is
    free again once its holder ends. The holder's own process may take it again (the harness calls
    the trainer under its lock)."""
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", "import sys\nfrom pathlib import Path\n"
                               "from contracts.folder_lock import folder_lock\n"
                               "with folder_lock(Path(sys.argv[1])):\n    print('held', flush=True)\n    sys.stdin.read()\n",
                               str(out)], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert lock_held(out)
        assert main([str(splat), "--out", str(out)] + TINY) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"train-and-evaluate: error: {out.absolute()}: in use by another running job (process "
                       f"{holder.pid} holds {lock_path(out)}); wait for it to finish or choose another folder"]
        assert not out.exists()
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    assert not lock_held(out)
    with folder_lock(out):
        refuse_if_busy(out)
        with folder_lock(out, wait=False):
            assert not lock_held(out)
