"""End-to-end `train-and-evaluate` at tiny budgets: outputs, resume, NaN handling, edge scenes.

The scenes come from `write_splat_dataset` (bpy-free, see test_smokeseer_data.py), except the
demo test, which uses the real generator through the `demo_dataset` fixture.
"""
from __future__ import annotations

import csv
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import torch
from matplotlib import colormaps
from PIL import Image
from scipy import ndimage

from smokeseer.cli import main
from smokeseer.evaluation.figures import figure_path
from smokeseer.config import DeformConfig
from smokeseer.model.deform import fourier_bases, motion_offsets, motion_tensors
from smokeseer.raster import read_ply
from smokeseer.train.stage2 import Stage2Problem
from smokeseer.train.stage3 import Stage3Problem, smoke_free_centres
from contracts.results_format import validate_run_dir
from tests.test_smokeseer_data import write_splat_dataset

TINY = ["--iterations-stage2", "12", "--iterations-stage3", "12", "--no-progress",
        "--set", "stage2.init_points=300", "--set", "stage3.smoke_points=120",
        "--set", "log_every=3", "--set", "stage3.test_every=6", "--set", "checkpoint_every=6",
        "--set", "stage2.deform_warmup=0.25", "--set", "stage3.deform_warmup=0.25"]


def _log_rows(run: Path) -> list[dict[str, str]]:
    with (run / "train_log.csv").open() as fh:
        return list(csv.DictReader(fh))


def _assert_complete(run: Path, thermal: bool = True) -> dict:
    doc = validate_run_dir(run)
    assert doc["status"] == "ok"
    assert doc["warnings"] == [], doc["warnings"]  # well-formed input, a sound optimisation: nothing to say
    assert doc["stages"]["thermal_used"] is thermal
    diagnostics = doc["surface_diagnostics"]  # the surface's own errors beside its PSNR
    assert 0.0 <= diagnostics["surface_alpha_under_0_9"] <= 1.0 and all(
        math.isfinite(diagnostics[k]) for k in ("psnr_surface_pixels", "psnr_surface_pixels_on_black"))
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


def _panels(png: Path) -> list[np.ndarray]:
    """The figure's image panels, left to right: the large blocks of non-white pixels (title
    glyphs are small blocks)."""
    img = np.asarray(Image.open(png).convert("RGB"))
    labels, _ = ndimage.label(np.any(img < 255, axis=-1))
    boxes = [b for b in ndimage.find_objects(labels) if (b[0].stop - b[0].start) * (b[1].stop - b[1].start) > 4000]
    return [img[b] for b in sorted(boxes, key=lambda b: b[1].start)]


def _native(panel: np.ndarray, height: int, width: int) -> np.ndarray:
    """A magnified panel sampled back at the centres of the source image's pixels."""
    rows = ((np.arange(height) + 0.5) * panel.shape[0] / height).astype(int)
    cols = ((np.arange(width) + 0.5) * panel.shape[1] / width).astype(int)
    return panel[rows][:, cols].astype(np.float64) / 255.0


def _assert_figures(run: Path, dataset: Path) -> None:
    """One figure per test view with four panels, in order: the smoky input, the thermal frame
    nearest in time, the surface render and the clean truth, each checked against its file."""
    doc = json.loads((run / "metrics.json").read_text())
    stems = [e["file_stem"] for e in doc["per_image"]]
    assert sorted(p.name for p in (run / "figures").iterdir()) == sorted(figure_path(run, s).name for s in stems)
    rgb = {f["file_stem"]: f for f in json.loads((dataset / "transforms_rgb.json").read_text())["frames"]}
    thermal = json.loads((dataset / "transforms_thermal.json").read_text())["frames"]
    inferno = colormaps["inferno"](np.linspace(0.0, 1.0, 256))[:, :3]
    for stem in stems:
        panels = _panels(figure_path(run, stem))
        assert len(panels) == 4
        smoky, clean, surface = (np.asarray(Image.open(p).convert("RGB"), dtype=np.float64) / 255.0 for p in
                                 (dataset / "rgb" / "smoky" / f"{stem}.png", dataset / "rgb" / "clean" / f"{stem}.png",
                                  run / "renders" / "surface" / f"{stem}.png"))
        h, w = smoky.shape[:2]
        for panel, truth in zip((panels[0], panels[2], panels[3]), (smoky, surface, clean)):
            assert np.abs(_native(panel, h, w) - truth).mean() < 0.01
        near = min(thermal, key=lambda f: abs(f["time"] - rgb[stem]["time"]))
        counts = np.asarray(Image.open(dataset / "thermal" / "smoky" / f"{near['file_stem']}.png"), dtype=np.float64)
        shown = _native(panels[1], *counts.shape)
        level = np.argmin(((shown[..., None, :] - inferno) ** 2).sum(-1), axis=-1)
        assert np.corrcoef(level.ravel(), counts.ravel())[0, 1] > 0.999


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
    _assert_figures(run, splat)
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


BY_SMOKE_COLOUR = TINY + ["--set", "stage3.smoke_color=haze-lines", "--set", "stage3.surface_init=by-smoke-colour",
                          "--set", "loss.mask_floor_where=estimated-meeting"]


def test_two_surface_run_joins_both_stage2s_and_resumes(splat: Path, tmp_path: Path) -> None:
    """stage3.surface_init=by-smoke-colour without a trusted colour (this tiny scene's haze lines give
    no estimate): a second Stage 2 on the RGB frames, with its own checkpoint and no rows of its own in
    train_log.csv; Stage 3 starts from the kept RGB Gaussians plus the thermal ones in their holes
    (which ones: tests/test_surface_union.py), as metrics.json records; a rerun trains nothing again."""
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run)] + BY_SMOKE_COLOUR) == 0
    doc = _assert_complete(run)
    union = doc["stages"]["surface_union"]
    assert 0 < union["rgb_kept"] <= union["rgb"] and 0 < union["thermal_kept"] <= union["thermal"]
    assert union["fill_opaque_share"] == 0.5
    assert doc["stages"]["surface_gaussians"] == union["thermal_kept"] + union["rgb_kept"]  # no surface densification
    assert any(n.startswith("surface from both Stage 2s") for n in doc["stages"]["notes"])
    assert torch.load(run / "checkpoints" / "stage2_rgb.pt", weights_only=False)["done"]
    keys = [(r["stage"], r["iteration"]) for r in _log_rows(run)]
    assert len(keys) == len(set(keys))
    n_rows = len(keys)
    assert main([str(splat), "--out", str(run)] + BY_SMOKE_COLOUR) == 0
    assert len(_log_rows(run)) == n_rows
    assert json.loads((run / "metrics.json").read_text())["metrics"] == doc["metrics"]


def test_the_carve_by_smoke_drops_no_rgb_gaussian_and_says_how_much_it_fades(splat: Path, tmp_path: Path) -> None:
    """stage3.carve_by=depth-and-smoke (the share itself: tests/test_surface_union.py): the joined
    start keeps every RGB Gaussian, fading each one instead, and the record and note say so."""
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run)] + BY_SMOKE_COLOUR + ["--set", "stage3.carve_by=depth-and-smoke"]) == 0
    doc = _assert_complete(run)
    union = doc["stages"]["surface_union"]
    assert union["carve_by"] == "depth-and-smoke" and union["rgb_kept"] == union["rgb"] > 0
    assert 0.0 <= union["rgb_carve_share"] <= 1.0
    assert any("faded by the share of its views that see it in front of the thermal surface on smoke" in n
               for n in doc["stages"]["notes"])


def test_the_thermal_gate_trains_and_says_how_much_thermal_shapes_the_surface(splat: Path, tmp_path: Path) -> None:
    """stage3.thermal_surface_grad=smoky-views (the gradient itself: tests/test_gradient_gates.py):
    this tiny scene's smoke covers part of every view, so the mean share at the start lies strictly
    between 0 and 1, the note says so, and the run ends ok."""
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run)] + TINY + ["--set", "stage3.thermal_surface_grad=smoky-views"]) == 0
    notes = _assert_complete(run)["stages"]["notes"]
    note = next(n for n in notes if n.startswith("the thermal term moves each surface Gaussian"))
    assert 0.0 < float(note.split("mean ")[1].split(" ")[0]) < 1.0


def test_the_thermal_term_renders_sub_pixels_and_says_so(splat: Path, tmp_path: Path) -> None:
    """stage3.thermal_supersample=2 (the averaging itself: tests/test_thermal_supersample.py): the
    run ends ok, and its notes give the size the thermal term renders at, twice the frames'."""
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run)] + TINY + ["--set", "stage3.thermal_supersample=2"]) == 0
    notes = _assert_complete(run)["stages"]["notes"]
    note = next(n for n in notes if n.startswith("the thermal term averages 2x2 sub-pixels"))
    rendered, frames = re.search(r"\((\d+x\d+) rendered for (\d+x\d+);", note).groups()
    assert [int(v) for v in rendered.split("x")] == [2 * int(v) for v in frames.split("x")]


def test_stage2_starts_from_points_triangulated_in_the_training_frames(splat: Path, tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """stage2.init_from=images (the triangulation itself: tests/test_triangulation.py): Stage 2
    starts from the triangulated points filled up with random ones to stage2.init_points, in the
    box around them, and the notes and metrics.json say how many."""
    from smokeseer import api

    monkeypatch.setenv("SMOKESEER_SFM_CACHE", str(tmp_path / "cache"))
    starts: list[int] = []
    train_stage2 = api.train_stage2

    def recording(ctx, mod, init_points, *args, **kwargs):
        starts.append(len(init_points))
        return train_stage2(ctx, mod, init_points, *args, **kwargs)

    monkeypatch.setattr(api, "train_stage2", recording)
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run)] + TINY + ["--set", "stage2.init_from=images"]) == 0
    doc = _assert_complete(run)
    record = doc["stages"]["start_points"]
    assert record["source"] == "triangulated from the training RGB frames at their poses" and record["points"] > 0
    assert any(n.startswith(f"stage 2 start: {record['points']} starting points triangulated") for n in doc["stages"]["notes"])
    assert starts[0] == max(record["points"], 300)


def test_an_environment_learning_from_clear_pixels_trains_both_stages(splat: Path, tmp_path: Path) -> None:
    """background_from=clear-pixels (the gradient itself: tests/test_gradient_gates.py) through an RGB
    Stage 2 and Stage 3 on this tiny scene's masks: the run ends ok and records the setting."""
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run), "--mode", "rgb-only"] + TINY
                + ["--set", "background_from=clear-pixels"]) == 0
    _assert_complete(run, thermal=False)
    assert json.loads((run / "config.json").read_text())["background_from"] == "clear-pixels"


def test_stage3_restarts_the_surface_at_sh_degree_0_and_its_position_rate_decays_as_the_smokes(
        splat: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Stage 3's RGB render starts at SH degree 0, and the surface's position rate equals the
    smoke's at every step, decaying from lr.means_init × extent (carrying Stage 2's on was level on
    24 scenes: docs/experiments/2026-12-08-surface-continues.md)."""
    from smokeseer.model.scene import SceneModel
    from smokeseer.train.stage3 import Stage3Problem

    degrees: list[int] = []
    rates: list[tuple[float, float, float]] = []
    render_rgb, optimizer_step = SceneModel.render_rgb, Stage3Problem.optimizer_step

    def recording_render(self, view, *args, degree=None, **kwargs):
        if degree is not None:
            degrees.append(degree)
        return render_rgb(self, view, *args, degree=degree, **kwargs)

    def recording_step(self, it: int) -> None:
        optimizer_step(self, it)
        lr = {opt: next(g["lr"] for g in opt.param_groups if g["name"] == "means")
              for opt in (self.surface_optimizer, self.smoke_optimizer)}
        rates.append((lr[self.surface_optimizer], lr[self.smoke_optimizer], self.cfg.lr.means_init * self.ctx.extent))

    monkeypatch.setattr(SceneModel, "render_rgb", recording_render)
    monkeypatch.setattr(Stage3Problem, "optimizer_step", recording_step)
    assert main([str(splat), "--out", str(tmp_path / "run")] + TINY) == 0
    surface, smoke, init = zip(*rates)
    assert len(surface) == 12 and degrees[0] == 0
    np.testing.assert_allclose(surface, smoke, rtol=1e-6)
    assert init[0] >= surface[0] > surface[-1] > 0


def test_the_bound_mask_term_trains_and_says_where_it_pushes(splat: Path, tmp_path: Path) -> None:
    """loss.mask_floor_where=estimated-bound: the targets are made once Stage 3's geometry is known,
    the note gives the share of masked pixels pushed and their mean target, and the run ends ok."""
    run = tmp_path / "run"
    rule = [{"loss.mask_floor_where=estimated-meeting": "loss.mask_floor_where=estimated-bound"}.get(a, a)
            for a in BY_SMOKE_COLOUR]
    assert main([str(splat), "--out", str(run)] + rule) == 0
    stages = _assert_complete(run)["stages"]
    assert stages["stage3_plan"]["mask_floor"] == "estimated-bound"
    note = next(n for n in stages["notes"] if n.startswith("mask term pushes the smoke alpha up"))
    assert "% of the masked training pixels, mean target" in note


def test_by_smoke_colour_keeps_the_rgb_stage2_by_one_minus_the_surface_trust(
        splat: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """stage3.surface_init=by-smoke-colour: this tiny scene's haze lines give no estimate, so Stage 3
    starts from the RGB Stage 2 with the thermal Gaussians in its holes; at trust 0.5 from the same
    with the RGB opacities halved; at trust 1 (a dark colour whose lines meet) from the thermal
    Stage 2 alone, never training the RGB one. Each says so in its notes. The mask floor then
    reads the surface Stage 3 starts from (the joined one, for the fill)."""
    from smokeseer import api
    from smokeseer.stage1.haze_lines import SmokeColourEstimate

    rule = BY_SMOKE_COLOUR
    thin = tmp_path / "thin"
    assert main([str(splat), "--out", str(thin)] + rule) == 0
    stages = _assert_complete(thin)["stages"]
    assert stages["surface_union"]["fill_opaque_share"] == 0.5 and (thin / "checkpoints" / "stage2_rgb.pt").exists()
    assert stages["surface_union"]["rgb_opacity_share"] == 1.0
    assert any("at 1.000 × its opacities" in n and "haze-line surface trust 0.000" in n for n in stages["notes"])
    assert stages["stage3_plan"]["mask_floor"] == "estimated-meeting"
    assert any(n.startswith("mask floor on") for n in stages["notes"])
    colour = np.array([0.21, 0.2, 0.23])

    def stages_under(name: str, trust: float, surface_trust: float) -> dict:
        """The stages record of a run whose haze lines give ``colour`` at these two trusts."""
        monkeypatch.setattr(api, "estimate_smoke_colour", lambda *a, **k: SmokeColourEstimate(
            colour, 500, 900, 0.8, meeting=colour, trust=trust, surface_trust=surface_trust))
        assert main([str(splat), "--out", str(tmp_path / name)] + rule) == 0
        return _assert_complete(tmp_path / name)["stages"]

    stages = stages_under("half", 0.25, 0.5)
    assert stages["surface_union"]["rgb_opacity_share"] == 0.5   # the start follows the surface trust ...
    assert stages["smoke_colour"]["haze_lines"]["trust"] == 0.25   # ... and the colour its own
    assert stages["smoke_colour"]["haze_lines"]["surface_trust"] == 0.5
    assert stages["surface_union"]["thermal_kept"] >= json.loads((thin / "metrics.json").read_text())[
        "stages"]["surface_union"]["thermal_kept"]   # a fainter RGB surface has more holes
    assert any("at 0.500 × its opacities" in n for n in stages["notes"])
    stages = stages_under("dense", 0.5, 1.0)
    assert stages["surface_union"] is None and not (tmp_path / "dense" / "checkpoints" / "stage2_rgb.pt").exists()
    assert any("surface from the thermal Stage 2 alone" in n for n in stages["notes"])
    assert main([str(splat), "--out", str(tmp_path / "bad"), "--set", "stage3.surface_init=by-smoke-colour"]
                + TINY) == 2
    assert not (tmp_path / "bad").exists()


class _Interrupted(Exception):
    """Stands for a killed process: raised inside Stage 3, caught by the test."""


DENSIFY = ["--set", "stage2.densify.start=0.17", "--set", "stage2.densify.every=4",
           "--set", "stage2.densify.grad_threshold=0", "--set", "stage3.smoke_densify.start=0.17",
           "--set", "stage3.smoke_densify.every=4", "--set", "stage3.smoke_densify.grad_threshold=0"]
"""Clone or split every Gaussian every 4 iterations of both stages (the split positions draw from their streams)."""


def run_stopped_and_resumed(dataset: Path, run: Path, args: list[str], stop_at: int,
                            monkeypatch: pytest.MonkeyPatch, problem: type = Stage3Problem,
                            before_resume: Callable[[], None] | None = None) -> None:
    """Train ``dataset`` into ``run``, stopped (``_Interrupted``) at iteration ``stop_at`` of
    ``problem``'s stage, then (after ``before_resume``) started again to the end."""
    forward = problem.forward

    def stopping(self, it: int):
        if it == stop_at:
            raise _Interrupted
        return forward(self, it)

    monkeypatch.setattr(problem, "forward", stopping)
    with pytest.raises(_Interrupted):
        main([str(dataset), "--out", str(run)] + args)
    monkeypatch.setattr(problem, "forward", forward)
    if before_resume is not None:
        before_resume()
    assert main([str(dataset), "--out", str(run)] + args) == 0


def _recording_draws(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, int]]:
    """Every view index the stages draw, as (stage, index), in order."""
    import smokeseer.train.stage2 as stage2
    import smokeseer.train.stage3 as stage3

    drawn: list[tuple[int, int]] = []
    real = stage2.draw_index

    def recording(stage: int):
        def draw(generator: torch.Generator, n: int) -> int:
            drawn.append((stage, real(generator, n)))
            return drawn[-1][1]
        return draw

    for module, stage in ((stage2, 2), (stage3, 3)):
        monkeypatch.setattr(module, "draw_index", recording(stage))
    return drawn


@pytest.mark.parametrize("stage, stop_at", [(3, 1), (3, 8), (2, 8)])
def test_interrupted_run_resumes_to_the_same_model(splat: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   stage: int, stop_at: int) -> None:
    """A run stopped and started again draws exactly the views and splits of one that never stopped,
    and ends with the same bytes: stopped at Stage 3's first iteration it restarts Stage 3 from the
    finished Stage 2, at 8 from the Stage 3 checkpoint of iteration 6, and stopped in Stage 2 from
    Stage 2's. Densification splits every 4 iterations, so the split streams' states in the
    checkpoints matter as much as the view streams'."""
    drawn = _recording_draws(monkeypatch)
    assert main([str(splat), "--out", str(tmp_path / "whole")] + TINY + DENSIFY) == 0
    whole = list(drawn)
    run = tmp_path / "stopped"
    run_stopped_and_resumed(splat, run, TINY + DENSIFY, stop_at, monkeypatch,
                            Stage3Problem if stage == 3 else Stage2Problem, drawn.clear)
    resumed_at = 0 if stop_at == 1 else 6   # the last checkpoint before the stop
    redrawn = (12 - resumed_at) * (2 if stage == 3 else 1) + (24 if stage == 2 else 0)  # Stage 3 draws RGB + thermal
    assert len(drawn) == redrawn and drawn == whole[-redrawn:]
    for ply in ("surface.ply", "smoke_t0.50.ply"):
        assert (run / "ply" / ply).read_bytes() == (tmp_path / "whole" / "ply" / ply).read_bytes()
    whole_psnr = json.loads((tmp_path / "whole" / "metrics.json").read_text())["metrics"]["psnr"]
    assert json.loads((run / "metrics.json").read_text())["metrics"]["psnr"] == whole_psnr


def test_view_order_does_not_depend_on_densification(splat: Path, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Views and split positions draw from separate streams: a run whose densification splits every
    4 iterations (drawing split positions) draws the same views in the same order as one that never
    densifies, in both stages, though the models differ. RGB-only's Stage 3 draws the same RGB views
    as Full's, which also draws thermal ones."""
    drawn = _recording_draws(monkeypatch)
    counts, orders = {}, {}
    for name, extra in (("plain", []), ("densified", DENSIFY)):
        drawn.clear()
        assert main([str(splat), "--out", str(tmp_path / name)] + TINY + extra) == 0
        orders[name] = list(drawn)
        counts[name] = json.loads((tmp_path / name / "metrics.json").read_text())["stages"]["smoke_gaussians"]
    assert counts["densified"] > counts["plain"]
    assert orders["densified"] == orders["plain"] and len(orders["plain"]) == 12 + 24

    rgb: dict[str, list[int]] = {}
    forward = Stage3Problem.forward

    def recording(self, it: int):
        out = forward(self, it)
        rgb[self.cfg.mode].append(out.extra["index"])
        return out

    monkeypatch.setattr(Stage3Problem, "forward", recording)
    for mode in ("full", "rgb-only"):
        rgb[mode] = []
        assert main([str(splat), "--out", str(tmp_path / f"views-{mode}"), "--mode", mode] + TINY) == 0
    assert rgb["full"] == rgb["rgb-only"] and len(rgb["full"]) == 12


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
    _assert_figures(run, splat)
    assert doc["method"] == mode and math.isfinite(doc["metrics"]["psnr"])
    if mode == "deformable-3dgs":
        assert doc["stages"]["smoke_gaussians"] == 0 and doc["metrics"]["mask_iou"] is None
        assert doc["stages"]["deformation"] is True  # its one set deforms
        assert doc["stages"]["geometry_modality"] == "rgb"
    if mode == "rgb-only":
        assert doc["stages"]["geometry_modality"] == "rgb"
        assert not (run / "renders" / "thermal").exists()


def test_surface_refinement_densifies_the_surface_only_when_asked(splat: Path, tmp_path: Path) -> None:
    """With stage3.surface_densify on, Stage 3 clones/splits/prunes the surface from the RGB views'
    gradients (the surface count leaves Stage 2's); off, the count is Stage 2's. Either way the
    run is complete and the surface PLY matches the reported count."""
    counts = {}
    for name, extra in (("off", []), ("on", ["--set", "stage3.surface_densify.every=3",
                                              "--set", "stage3.surface_densify.start=0.25",
                                              "--set", "stage3.surface_densify.grad_threshold=0.0"])):
        run = tmp_path / name
        assert main([str(splat), "--out", str(run)] + TINY + extra) == 0
        doc = _assert_complete(run)
        stage2 = [int(r["n_gaussians"]) for r in _log_rows(run) if r["stage"] == "2"][-1]
        counts[name] = (stage2, doc["stages"]["surface_gaussians"])
    assert counts["off"][1] == counts["off"][0]
    assert counts["on"][0] == counts["off"][0] and counts["on"][1] > counts["on"][0]


def test_smoke_free_centres_gate_on_the_centre_pixel() -> None:
    """Analytic case: smoke covers the left half of a 4x2 image; a centre at pixel x in [0, 2) is
    smoky, in [2, 4) clear, outside the image not counted, and no smoke model means all clear."""
    cover = torch.tensor([[0.9, 0.5, 0.0, 0.02], [0.9, 0.5, 0.0, 0.02]])
    centres = torch.tensor([[0.5, 0.5], [1.99, 1.5], [2.0, 0.2], [3.9, 1.9], [-0.1, 0.5], [4.0, 1.0], [2.5, 2.0]])
    assert smoke_free_centres(centres, cover, 0.02).tolist() == [False, False, True, True, False, False, False]
    assert smoke_free_centres(centres, cover, 1.0).tolist() == [True] * 4 + [False] * 3
    assert smoke_free_centres(centres, None, 0.02).all()
    # gsplat leaves the centres of the Gaussians it culls unwritten: any bits, NaN included
    junk = torch.tensor([[float("nan"), 0.5], [0.5, float("nan")], [float("inf"), 1.0], [-1e30, 1.0]])
    assert smoke_free_centres(junk, cover, 1.0).tolist() == [False] * 4


def test_surface_refinement_grows_no_surface_where_stage1_sees_only_smoke(tmp_path: Path) -> None:
    """When the Stage 1 masks call every pixel smoke, refinement gated on smoke-free centres has
    no gradient to grow from, so the surface cannot gain Gaussians; counting every pixel
    (max_smoke 1.0) the same run grows it, as the ungated refinement did."""
    ds = write_splat_dataset(tmp_path / "ds", n_rgb=8, n_thermal=6)
    for mask in (ds / "rgb" / "smoke_mask").glob("*.png"):
        Image.fromarray(np.full_like(np.asarray(Image.open(mask)), 255)).save(mask)
    refine = ["--set", "stage3.surface_densify.every=3", "--set", "stage3.surface_densify.start=0.25",
              "--set", "stage3.surface_densify.grad_threshold=1e-12"]
    counts = {}
    for max_smoke in (0.02, 1.0):
        run = tmp_path / f"run-{max_smoke}"
        assert main([str(ds), "--out", str(run)] + TINY + refine
                    + ["--set", f"stage3.surface_densify_max_smoke={max_smoke}"]) == 0
        doc = _assert_complete(run)
        stage2 = [int(r["n_gaussians"]) for r in _log_rows(run) if r["stage"] == "2"][-1]
        counts[max_smoke] = (stage2, doc["stages"]["surface_gaussians"])
    assert counts[0.02][1] <= counts[0.02][0]
    assert counts[1.0][1] > counts[1.0][0]


def test_training_opens_no_ground_truth_of_its_training_frames(splat: Path, tmp_path: Path) -> None:
    """Training reads only what a real capture has, plus the declared oracle Stage 1 (masks,
    poses, smoke flags). A copy of the dataset whose training frames' clean and shadowed frames,
    depth and smoke alpha (every ground-truth folder, ``GROUND_TRUTH_FOLDERS``; for thermal, every
    frame) are overwritten with bytes no reader accepts trains to the same bytes as the original, at
    the standard profile's rules: the mask floor estimated from the images, held-out
    validation frames, the haze-line smoke colour and Stage 3's surface chosen by it."""
    import shutil

    from contracts.dataset_format import GROUND_TRUTH_FOLDERS
    from scenes.load import load_scene

    standard_rules = BY_SMOKE_COLOUR + ["--set", "validation_every=4", "--set", "stage3.smoke_color_min_meeting=0.2",
                                        "--set", "stage3.smoke_color_max_brightness=0.5"]
    scored = {f.file_stem for f in load_scene(splat, validation_every=4).rgb.frames if f.split != "train"}
    spoiled = tmp_path / "spoiled"
    shutil.copytree(splat, spoiled)
    broken: set[str] = set()
    for folder in GROUND_TRUTH_FOLDERS:
        for file in (spoiled / folder).glob("*.*"):
            if folder.startswith("thermal/") or file.stem not in scored:
                file.write_bytes(b"not an image")
                broken.add(folder)
    assert {"rgb/clean", "rgb/depth", "rgb/smoke_alpha"} <= broken  # rgb/shadowed: a test-view pass, none to break
    for name, data in (("original", splat), ("spoiled", spoiled)):
        assert main([str(data), "--out", str(tmp_path / name)] + standard_rules) == 0
    a, b = tmp_path / "original", tmp_path / "spoiled"
    assert (a / "ply" / "surface.ply").read_bytes() == (b / "ply" / "surface.ply").read_bytes()
    ma, mb = (json.loads((d / "metrics.json").read_text()) for d in (a, b))
    assert ma["metrics"] == mb["metrics"] and ma["validation"] == mb["validation"]
    assert any("loss.mask_floor_where=estimated-meeting" in n for n in ma["stages"]["notes"])


def test_mask_alpha_floor_reaches_the_mask_term(splat: Path, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """loss.mask_alpha_floor is the floor Stage 3's mask term uses (default 0.4, the public code's),
    and loss.mask_floor_where=never-clear or estimated-meeting hands it a per-pixel map of the mask's
    shape (said in stages.notes), a weight in [0, 1] with loss.mask_floor_meeting=trusted;
    estimated-bound hands it a target per pixel instead; by default it acts on every masked pixel."""
    import smokeseer.train.stage3 as stage3

    seen: list[tuple[float, tuple[int, ...] | None, bool]] = []
    term = stage3.mask_alignment

    def recording(alpha: torch.Tensor, mask: torch.Tensor, floor: float, floor_where: torch.Tensor | None = None,
                  targets: torch.Tensor | None = None) -> torch.Tensor:
        assert floor_where is None or floor_where.shape == mask.shape
        assert floor_where is None or floor_where.dtype == (torch.float32 if trusted else torch.bool)
        assert floor_where is None or bool(((floor_where >= 0) & (floor_where <= 1)).all())
        assert targets is None or (targets.dtype == mask.dtype and targets.shape == mask.shape
                                   and bool(((targets >= 0) & (targets <= 1)).all()))
        seen.append((floor, None if floor_where is None else tuple(floor_where.shape), targets is not None))
        return term(alpha, mask, floor, floor_where, targets)

    monkeypatch.setattr(stage3, "mask_alignment", recording)
    estimated = ["--set", "loss.mask_floor_where=estimated-meeting", "--set", "stage3.smoke_color=haze-lines"]
    for name, extra, expected in (("default", [], 0.4), ("floor", ["--set", "loss.mask_alpha_floor=0.9"], 0.9),
                                  ("gated", ["--set", "loss.mask_floor_where=never-clear"], 0.4),
                                  ("estimated", estimated, 0.4),
                                  ("trusted", estimated + ["--set", "loss.mask_floor_meeting=trusted"], 0.4),
                                  ("bound", ["--set", "loss.mask_floor_where=estimated-bound",
                                             "--set", "stage3.smoke_color=haze-lines"], 0.4)):
        seen.clear()
        trusted = name == "trusted"
        assert main([str(splat), "--out", str(tmp_path / name)] + TINY + extra) == 0
        assert seen and {f for f, _, _ in seen} == {expected}
        gated = {shape is not None for _, shape, _ in seen}
        assert gated == {name in ("gated", "estimated", "trusted")}
        assert {t for _, _, t in seen} == {name == "bound"}
        notes = json.loads((tmp_path / name / "metrics.json").read_text())["stages"]["notes"]
        assert any("mask floor on" in n for n in notes) == (name in ("gated", "estimated", "trusted"))
        assert any("loss.mask_floor_where=estimated-meeting)" in n for n in notes) == (name in ("estimated", "trusted"))


@pytest.mark.parametrize("smoke", ["none", "opaque"])
def test_no_smoke_and_opaque_smoke_train_without_nan(tmp_path: Path, smoke: str) -> None:
    # The opaque scene is also flagged static: that must drop the deformation network. Both train
    # under the standard profile's rules (Stage 3's start chosen by the smoke colour, the floor
    # read off the images); without smoke that start is the RGB surface with the thermal fill.
    ds = write_splat_dataset(tmp_path / smoke, smoke=smoke, n_rgb=8, n_thermal=6, static_flag=smoke == "opaque")
    run = tmp_path / f"run-{smoke}"
    assert main([str(ds), "--out", str(run)] + BY_SMOKE_COLOUR) == 0
    doc = validate_run_dir(run)
    assert doc["status"] == "ok"
    if smoke == "none":
        assert doc["stages"]["smoke_gaussians"] == 0 and doc["metrics"]["mask_iou"] is None
        assert doc["stages"]["deformation"] is False  # no smoke, so no smoke deformation network
        assert doc["stages"]["surface_union"] is not None
        assert any("the run has no smoke, so the RGB sees the surface" in n for n in doc["stages"]["notes"])
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
    assert nan_ck["iteration"] == int(found.group(2)) - 1
    assert all(bool(torch.isfinite(t).all()) for t in nan_ck["gaussians"].values())
    doc = validate_run_dir(run)
    assert doc["status"] == "failed" and "NaNDetected" in doc["error"] and "metrics" not in doc
    assert (run / "checkpoints" / "stage2_nan.pt").is_file()


def test_failed_kernel_build_is_one_line_and_exit_2(splat: Path, tmp_path: Path) -> None:
    """A compiler that cannot build the CPU rasterizer ends the CLI with one error line, no traceback."""
    env = {**os.environ, "CXX": "/bin/false", "TORCH_EXTENSIONS_DIR": str(tmp_path / "ext")}
    proc = subprocess.run([sys.executable, "-m", "smokeseer.cli", str(splat), "--out", str(tmp_path / "r")] + TINY,
                          env=env, cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 2, proc.stderr[-2000:]
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("train-and-evaluate:")]
    assert len(errors) == 1 and "could not build the CPU tile rasterizer" in errors[0], proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr


def test_bad_input_gives_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main([str(tmp_path / "nowhere"), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nowhere" in err[0] and err[0].startswith("train-and-evaluate: error:")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "dataset.json").write_text(json.dumps({"format": "smokeseer-synth-dataset", "passes": {"rgb": ["smoky"]}}))
    assert main([str(bad), "--out", str(tmp_path / "r2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "dataset.json" in err[0]
    assert main([str(bad), "--out", str(tmp_path / "r3"), "--set", "nope=1"]) == 2
    assert "overrides: unknown key 'nope'" in capsys.readouterr().err
    assert main([str(bad), "--out", str(tmp_path / "r4"), "--set", "depth_prior=mono",
                 "--set", "mono_weights=/nonexistent/depth.pt"]) == 2
    assert "mono_weights: no TorchScript file" in capsys.readouterr().err
    if not torch.cuda.is_available():
        assert main([str(bad), "--out", str(tmp_path / "r5"), "--device", "cuda"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "device: 'cuda' asked for, but this torch" in err[0] and "sees no CUDA GPU" in err[0]
    assert main([str(bad), "--out", str(tmp_path / "r6"), "--device", "gpu0"]) == 2
    assert "device: 'gpu0' is not a torch device" in capsys.readouterr().err
    assert not any((tmp_path / name).exists() for name in ("r", "r2", "r3", "r4", "r5", "r6"))


def test_out_that_is_a_file_is_one_line_before_any_work(splat: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture) -> None:
    """``--out FILE`` (or a run folder under a file) is refused before the dataset is read, and the
    file is left as it was."""
    taken = tmp_path / "taken.txt"
    taken.write_text("kept")
    for out, what in ((taken, "the run folder"), (taken / "run", f"a parent of the run folder {taken / 'run'}")):
        assert main([str(splat), "--out", str(out)] + TINY) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"train-and-evaluate: error: {taken}: is a file, not a directory ({what})"]
    assert taken.read_text() == "kept" and sorted(p.name for p in tmp_path.iterdir()) == ["taken.txt"]


def test_folder_that_is_no_dataset_says_what_was_looked_for(splat: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture) -> None:
    """A generated dataset without its dataset.json is neither that nor a capture layout: the one
    line says so and names the files each would have, instead of a missing image."""
    bare = tmp_path / "bare"
    shutil.copytree(splat / "rgb", bare / "rgb")
    shutil.copy(splat / "transforms_rgb.json", bare / "transforms_rgb.json")
    assert main([str(bare), "--out", str(tmp_path / "run")] + TINY) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"train-and-evaluate: error: {bare}: neither a generated dataset "
                                               "(no dataset.json) nor a capture layout (no capture.json, rgb/images/")
    assert "transforms_train.json" in err[0] and "missing file" not in err[0]
    assert not (tmp_path / "run").exists()


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def test_truncated_exr_is_refused_before_training(splat: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture) -> None:
    """The validator of `generate-scene --validate` runs first: a damaged input file (a thermal
    radiance EXR, read for its check alone) is one line, exit 2, and nothing in --out."""
    ds = _copy(splat, tmp_path / "ds")
    victim = sorted((ds / "thermal" / "smoky_radiance").glob("*.exr"))[1]
    victim.write_bytes(victim.read_bytes()[:300])
    run = tmp_path / "run"
    assert main([str(ds), "--out", str(run)] + TINY) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and victim.name in err[0] and err[0].startswith("train-and-evaluate: error:")
    assert not run.exists()


def test_nan_checkpoint_holds_the_last_good_state(splat: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture) -> None:
    """An iteration that turns parameters non-finite must not be what the NaN checkpoint holds. A
    huge scale learning rate makes scales overflow when densification splits them (exp of
    ~1e5), so the split Gaussians' means are infinite (before, the checkpoint held them)."""
    run = tmp_path / "nan"
    assert main([str(splat), "--out", str(run), "--set", "lr.scales=1e5", "--set", "stage2.densify.start=0.17",
                 "--set", "stage2.densify.every=2", "--set", "stage2.densify.grad_threshold=0"] + TINY) == 1
    found = re.search(r"non-finite value in (\S+) at stage 2, iteration (\d+)", capsys.readouterr().err)
    assert found
    ck = torch.load(run / "checkpoints" / "stage2_nan.pt", weights_only=False)
    assert ck["iteration"] == int(found.group(2)) - 1
    for name, t in ck["gaussians"].items():
        assert bool(torch.isfinite(t).all()), name


def test_corrupt_checkpoint_is_an_error_not_a_restart(splat: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture) -> None:
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run)] + TINY) == 0
    capsys.readouterr()
    (run / "checkpoints" / "stage2.pt").write_bytes(b"not a checkpoint")
    assert main([str(splat), "--out", str(run)] + TINY) == 2
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert "Traceback" not in err and last.startswith("train-and-evaluate: error:")
    assert "stage2.pt: unreadable checkpoint" in last


def test_dropped_terms_are_said_in_the_log_and_metrics(splat: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture) -> None:
    ds = _copy(splat, tmp_path / "nomask")
    meta = json.loads((ds / "dataset.json").read_text())
    meta["passes"]["rgb"] = [p for p in meta["passes"]["rgb"] if p != "smoke_alpha"]
    (ds / "dataset.json").write_text(json.dumps(meta))
    run = tmp_path / "run"
    assert main([str(ds), "--out", str(run), "--mode", "no-mask", "--set", "stage3.train_surface_geometry=false"]
                + TINY) == 0
    err = capsys.readouterr().err
    notes = json.loads((run / "metrics.json").read_text())["stages"]["notes"]
    for needle in ("mask term dropped: the dataset has no smoke masks, so this no-mask run trains exactly like full",
                   "depth term dropped: stage3.train_surface_geometry is false"):
        assert any(needle in n for n in notes) and needle in err


def test_haze_line_smoke_colour_is_blended_by_its_trust_aloud(splat: Path, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture) -> None:
    """stage3.smoke_color=haze-lines: a fully trusted estimate becomes every smoke Gaussian's colour
    (clones included) and stays so through training, with the colour priors off; at trust 0.5 each
    Gaussian shows half the estimate and half its own colour, which learns, with the priors on; on
    this tiny scene the real estimator finds too few lines, and the run says it learns the colours."""
    from smokeseer import api
    from smokeseer.stage1.haze_lines import SmokeColourEstimate

    refused = tmp_path / "refused"
    assert main([str(splat), "--out", str(refused), "--set", "stage3.smoke_color=haze-lines"] + TINY) == 0
    stages = json.loads((refused / "metrics.json").read_text())["stages"]
    lines = stages["smoke_colour"]["haze_lines"]
    assert stages["smoke_colour"]["source"] == "learned" and lines["limits"] and lines["trust"] == 0.0
    assert any(n.startswith("smoke colour: the haze-line estimate has no trust") for n in stages["notes"])
    assert "smoke colour: the haze-line estimate has no trust" in capsys.readouterr().err

    colour = np.array([0.21, 0.2, 0.23])
    densify = ["--set", "stage3.smoke_densify.start=0.25", "--set", "stage3.smoke_densify.every=3",
               "--set", "stage3.smoke_densify.grad_threshold=0"]
    monkeypatch.setattr(api, "estimate_smoke_colour",
                        lambda *a, **k: SmokeColourEstimate(colour, 500, 900, 0.8, trust=1.0))
    run = tmp_path / "fixed"
    assert main([str(splat), "--out", str(run), "--set", "stage3.smoke_color=haze-lines"] + densify + TINY) == 0
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["stages"]["smoke_colour"]["source"] == "haze-lines"
    assert doc["stages"]["smoke_colour"]["haze_lines"]["trust"] == 1.0
    assert "smoke_color and mono terms dropped: the smoke colour is held fixed" in " ".join(doc["stages"]["notes"])
    assert doc["stages"]["smoke_colour"]["haze_lines"]["colour"] == pytest.approx(colour.tolist())
    smoke = torch.load(run / "checkpoints" / "stage3.pt", weights_only=False)["smoke"]
    assert smoke["color"].shape[0] > 120  # densified: the clones carry the colour too
    assert torch.count_nonzero(smoke["color"]) == 0   # the learned part never moves: no gradient reaches it
    rows = [r for r in _log_rows(run) if r["stage"] == "3"]
    assert rows and not any(r.get("smoke_color") or r.get("mono") for r in rows)

    monkeypatch.setattr(api, "estimate_smoke_colour",
                        lambda *a, **k: SmokeColourEstimate(colour, 250, 900, 0.3, trust=0.5))
    half = tmp_path / "half"
    assert main([str(splat), "--out", str(half), "--set", "stage3.smoke_color=haze-lines"] + TINY) == 0
    doc = json.loads((half / "metrics.json").read_text())
    assert doc["stages"]["smoke_colour"]["haze_lines"]["trust"] == 0.5
    assert not {"smoke_color", "mono"} & set(doc["stages"]["stage3_plan"]["dropped"])
    assert any("each smoke Gaussian shows 0.500 × the haze-line estimate" in n for n in doc["stages"]["notes"])
    smoke = torch.load(half / "checkpoints" / "stage3.pt", weights_only=False)["smoke"]
    assert torch.count_nonzero(smoke["color"]) > 0   # the learned half trains
    rows = [r for r in _log_rows(half) if r["stage"] == "3"]
    assert all(r.get("smoke_color") and r.get("mono") for r in rows)
    assert main([str(splat), "--out", str(tmp_path / "bad"), "--set", "stage3.smoke_color=guessed"] + TINY) == 2
    assert "stage3.smoke_color: 'guessed' is not one of learned, haze-lines" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_equalised_thermal_is_recorded_and_rendered_in_raw_counts(splat: Path, tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:
    """thermal_scale=equalised: the curve goes in the log and stages.thermal_scale, the Stage-2
    checkpoint is keyed apart from the linear one, and the thermal renders come back in raw counts."""
    from smokeseer.config import make_config

    run = tmp_path / "equalised"
    assert main([str(splat), "--out", str(run), "--set", "thermal_scale=equalised"] + TINY) == 0
    err = capsys.readouterr().err
    record = json.loads((run / "metrics.json").read_text())["stages"]["thermal_scale"]
    assert record["kind"] == "equalised" and record["bins"] == 2048 and 0 < record["crowded"] <= 1
    assert "stage 1: thermal scale equalised over raw" in err
    lo, hi = record["raw_range"]
    renders = np.stack([np.asarray(Image.open(p)) for p in sorted((run / "renders" / "thermal").glob("*.png"))])
    assert renders.min() >= math.floor(lo) and renders.max() <= math.ceil(hi) and renders.std() > 0
    linear, equalised = make_config("full", "quick", 0, {}), make_config("full", "quick", 0, {"thermal_scale": "equalised"})
    assert linear.stage2_sha256() != equalised.stage2_sha256()
    rgb = [make_config("rgb-only", "quick", 0, o).stage2_sha256() for o in ({}, {"thermal_scale": "equalised"})]
    assert rgb[0] == rgb[1]  # RGB-only never reads the thermal frames: its Stage 2 is shared
    assert main([str(splat), "--out", str(tmp_path / "bad"), "--set", "thermal_scale=agc"] + TINY) == 2
    assert "thermal_scale: 'agc' is not one of linear, equalised" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_metrics_name_the_commit_threads_and_machine(splat: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run)] + TINY) == 0
    prov = validate_run_dir(run)["provenance"]
    assert prov["threads"] == torch.get_num_threads() and prov["machine"]["cpu_count"]
    assert len(prov["source_digest"]) == 64
    if (Path(__file__).resolve().parents[1] / ".git").exists():
        assert re.fullmatch(r"[0-9a-f]{40}", prov["commit"])


def test_provenance_is_taken_before_training(splat: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A commit made, or a file edited, while a long run trains must not be credited with it:
    metrics.json carries the provenance read before Stage 2 began."""
    from smokeseer import api

    reads: list[str] = []
    real_provenance, real_stage2 = api.provenance, api.train_stage2

    def provenance(*args, **kwargs):
        reads.append("during training" if "stage 2" in reads else "before training")
        return {**real_provenance(*args, **kwargs), "commit": reads[-1]}

    def train_stage2(*args, **kwargs):
        reads.append("stage 2")
        return real_stage2(*args, **kwargs)

    monkeypatch.setattr(api, "provenance", provenance)
    monkeypatch.setattr(api, "train_stage2", train_stage2)
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run)] + TINY) == 0
    assert json.loads((run / "metrics.json").read_text())["provenance"]["commit"] == "before training"


def test_paper_profile_on_cpu_prints_its_estimate_first(splat: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture) -> None:
    run = tmp_path / "paper"
    assert main([str(splat), "--out", str(run), "--profile", "paper", "--iterations-stage2", "2",
                 "--iterations-stage3", "2", "--no-progress", "--set", "stage2.init_points=200",
                 "--set", "stage3.smoke_points=50", "--set", "deform.width=32"]) == 0
    err = capsys.readouterr().err
    assert "profile paper on the CPU" in err and "estimated at least" in err
    assert err.index("estimated at least") < err.index("stage 2:")
    assert json.loads((run / "metrics.json").read_text())["wall_time_s"]["estimated_min"] > 0


def _train_on_meta_default(splat: Path, out: Path) -> None:
    from smokeseer.api import train_and_evaluate

    overrides = {"stage2.iterations": 12, "stage3.iterations": 12, "stage2.init_points": 300,
                 "stage3.smoke_points": 120, "log_every": 3, "stage3.test_every": 6, "checkpoint_every": 6,
                 "stage2.deform_warmup": 0.25, "stage3.deform_warmup": 0.25, "progress": False,
                 # densify inside the tiny budget, so its buffers and draws are exercised
                 "stage2.densify.start": 0.17, "stage2.densify.every": 4, "stage2.densify.grad_threshold": 0.0,
                 "stage3.smoke_densify.start": 0.17, "stage3.smoke_densify.every": 4,
                 "stage3.smoke_densify.grad_threshold": 0.0}
    torch.set_default_device("meta")
    try:
        train_and_evaluate(splat, out, "full", overrides=overrides)
    finally:
        torch.set_default_device(None)


def test_every_tensor_is_made_on_the_parameters_device(splat: Path, tmp_path: Path) -> None:
    """With "meta" as the default device and the parameters on the CPU, any tensor created
    without an explicit device is a meta tensor and fails the moment it meets a real one."""
    _train_on_meta_default(splat, tmp_path / "run")
    assert validate_run_dir(tmp_path / "run")["status"] == "ok"


def test_device_check_catches_a_buffer_made_without_a_device(splat: Path, tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """The check above bites: densification state made the old way (no device) fails it."""
    from smokeseer.model import gaussians

    monkeypatch.setattr(gaussians.DensifyState, "zeros",
                        classmethod(lambda cls, n, device: cls(torch.zeros(n), torch.zeros(n), torch.zeros(n))))
    with pytest.raises((RuntimeError, NotImplementedError)):
        _train_on_meta_default(splat, tmp_path / "run")


def test_lpips_is_scored_by_the_trainer_when_weights_exist(splat: Path, tmp_path: Path) -> None:
    """Random weights stand in for the ImageNet backbone (none ships offline): the trainer scores
    LPIPS from its float renders at its own resolution."""
    from tests.test_metrics import _random_alex_files

    bb, hd = _random_alex_files(tmp_path)
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run), "--lpips-weights", bb, "--lpips-heads", hd] + TINY) == 0
    doc = validate_run_dir(run)
    assert doc["metrics"]["lpips_status"].startswith("ok: alex") and math.isfinite(doc["metrics"]["lpips"])
    assert all("lpips" in e for e in doc["per_image"])


def test_state_snapshot_is_an_independent_detached_copy() -> None:
    from smokeseer.train.loop import detached_copy

    p = torch.nn.Parameter(torch.randn(5, 3))
    opt = torch.optim.Adam([{"params": [p], "lr": 0.1, "name": "means"}], fused=True)
    p.grad = torch.randn(5, 3)
    opt.step()
    live = {"means": p, "optimizer": opt.state_dict()}
    snap = detached_copy(live)
    moment = snap["optimizer"]["state"][0]["exp_avg"]
    assert torch.equal(snap["means"], p.detach()) and not snap["means"].requires_grad
    assert type(snap["means"]) is torch.Tensor
    assert snap["optimizer"]["param_groups"] == live["optimizer"]["param_groups"]
    before = snap["means"].clone(), moment.clone()
    opt.step()  # the live state moves on; the snapshot does not
    assert torch.equal(snap["means"], before[0]) and torch.equal(moment, before[1])
    assert not torch.equal(p.detach(), before[0])


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
def test_guard_names_the_first_non_finite_tensor_and_passes_huge_finite_values(bad: float) -> None:
    from smokeseer.train.loop import guard
    from smokeseer.train.util import NaNDetected

    huge = torch.full((4, 3), 3e38)  # its 2-norm overflows to inf, yet every value is finite
    named = [("loss.render", torch.tensor(0.3)), ("a.grad", None), ("b", huge), ("c", torch.zeros(0)),
             ("d", torch.arange(5)), ("e", torch.ones(2, 2, dtype=torch.float64))]
    guard(3, 7, named)
    broken = torch.ones(6, 5)
    broken[4, 2] = bad
    with pytest.raises(NaNDetected) as exc:
        guard(3, 7, named + [("f.grad", broken), ("g.grad", torch.full((2,), bad))])
    assert (exc.value.stage, exc.value.iteration, exc.value.tensor) == (3, 7, "f.grad")


def test_fourier_bases_and_offsets_match_their_closed_form() -> None:
    """The bases at t are (t, sin kπt, cos kπt); an offset is the coefficients' sum over them, and
    its gradient with respect to a coefficient is that basis (autograd against the closed form)."""
    t, terms = 0.3, 3
    phi = fourier_bases(t, terms, torch.zeros(1, dtype=torch.float64))
    k = np.arange(1, terms + 1)
    assert phi.numpy() == pytest.approx(np.concatenate([[t], np.sin(k * np.pi * t), np.cos(k * np.pi * t)]), abs=1e-15)
    gen = torch.Generator().manual_seed(0)
    params = {key: torch.randn(5, 1 + 2 * terms, c, generator=gen, dtype=torch.float64, requires_grad=True)
              for key, c in (("motion_means", 3), ("motion_quats", 4), ("motion_log_scales", 3))}
    d_xyz, d_rot, d_scale = motion_offsets(params, t)
    for out, key in ((d_xyz, "motion_means"), (d_rot, "motion_quats"), (d_scale, "motion_log_scales")):
        assert out.detach().numpy() == pytest.approx(np.einsum("nbc,b->nc", params[key].detach().numpy(), phi.numpy()))
    d_xyz[2, 1].backward()
    expected = torch.zeros_like(params["motion_means"])
    expected[2, :, 1] = phi
    assert torch.equal(params["motion_means"].grad, expected)
    zero = motion_tensors(4, DeformConfig(fourier_terms=terms, predict_rotation_scale=False), torch.device("cpu"))
    assert set(zero) == {"motion_means"}
    assert motion_offsets(zero, 0.7)[0].abs().max() == 0 and motion_offsets(zero, 0.7)[1] is None


def test_fourier_motion_trains_the_smoke_without_a_network(splat: Path, tmp_path: Path) -> None:
    """deform.kind=fourier: no network in the checkpoint, every smoke Gaussian (densified or not)
    carries its own coefficients, they leave zero once the warm-up ends, and the placed smoke
    PLYs differ between times; the run is otherwise complete."""
    run = tmp_path / "run"
    assert main([str(splat), "--out", str(run), "--set", "deform.kind=fourier", "--set", "deform.fourier_terms=2",
                              "--set", "deform.predict_rotation_scale=true"] + TINY) == 0
    doc = _assert_complete(run)
    state = torch.load(run / "checkpoints" / "stage3.pt", map_location="cpu", weights_only=False)
    assert state["deform"] is None and state["deform_optimizer"] is None
    smoke = state["smoke"]
    assert doc["stages"]["smoke_gaussians"] == smoke["means"].shape[0] > 0
    for key, c in (("motion_means", 3), ("motion_quats", 4), ("motion_log_scales", 3)):
        assert tuple(smoke[key].shape) == (smoke["means"].shape[0], 5, c)
        assert smoke[key].abs().max() > 0
    plys = sorted((run / "ply").glob("smoke_t*.ply"))
    assert len(plys) >= 2
    assert not np.allclose(read_ply(plys[0]).means, read_ply(plys[-1]).means)


def test_fourier_motion_is_refused_for_the_deformable_baseline_and_checked() -> None:
    from smokeseer.config import make_config
    with pytest.raises(ValueError, match="deform.kind: the deformable-3dgs baseline is the MLP"):
        make_config("deformable-3dgs", overrides={"deform.kind": "fourier"})
    with pytest.raises(ValueError, match="deform.kind: 'spline' is not one of mlp, fourier, planes"):
        make_config(overrides={"deform.kind": "spline"})
    with pytest.raises(ValueError, match="deform.fourier_terms: must be at least 1"):
        make_config(overrides={"deform.kind": "fourier", "deform.fourier_terms": 0})


def test_training_renders_without_depth_train_the_same_bytes(splat: Path, tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """Training passes leave out the depth image they never read (a kernel channel per blended
    pair); forcing it back in every pass gives the same trained bytes, so leaving it out changes
    nothing but time. The forced run must really render it (a spy counts the depth images)."""
    from smokeseer.model import scene as scene_module
    original = scene_module.render
    drawn = {"with": 0, "without": 0}

    def spy(*args, force: bool, **kwargs):
        if force:
            kwargs["depth"] = True
        out = original(*args, **kwargs)
        drawn["with" if out.depths is not None else "without"] += 1
        return out

    states = []
    for force in (False, True):
        monkeypatch.setattr(scene_module, "render", lambda *a, force=force, **k: spy(*a, force=force, **k))
        monkeypatch.setattr("smokeseer.train.stage2.render", lambda *a, force=force, **k: spy(*a, force=force, **k))
        run = tmp_path / f"force{force}"
        assert main([str(splat), "--out", str(run), "--set", "depth_prior=none"] + TINY) == 0
        states.append(torch.load(run / "checkpoints" / "stage3.pt", map_location="cpu", weights_only=False))
        if not force:
            assert drawn["without"] >= 24 and drawn["with"] > 0  # training without, evaluation with
            drawn.update({"with": 0, "without": 0})
    assert drawn["without"] == 0
    for part in ("surface", "smoke"):
        assert states[0][part].keys() == states[1][part].keys()
        for key in states[0][part]:
            assert torch.equal(states[0][part][key], states[1][part][key]), f"{part}.{key}"
