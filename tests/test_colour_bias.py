"""The colour cast read from a finished run's saved renders (benchmarks/colour_bias.py) against the
trainer's own float measurement of it (metrics.json surface_diagnostics)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks.colour_bias import main, run_bias
from contracts.imageio import image01, read_png, write_png
from contracts.unrecoverable import dataset_unrecoverable
from scenes.load import load_scene
from smokeseer.cli import main as train
from tests.test_smokeseer_data import write_splat_dataset
from tests.test_trainer import TINY


def _as_harness_run(run: Path, dataset: Path) -> None:
    (run / "harness.json").write_text(json.dumps(
        {"scene": "splat", "variant": "full", "seed": 0, "status": "ok", "run_dir": str(run),
         "dataset": str(dataset), "code_digest": "c" * 64, "metrics": {}}))


def test_the_saved_renders_give_the_trainers_own_colour_bias(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """A tiny real run: its 8-bit renders give the bias the trainer measured on its float renders,
    to the 8-bit rounding (half a grey level, 0.002)."""
    dataset = write_splat_dataset(tmp_path / "splat")
    run = tmp_path / "tables" / "runs" / "splat" / "full" / "seed0-x"
    assert train([str(dataset), "--out", str(run)] + TINY) == 0
    _as_harness_run(run, dataset)
    recorded = json.loads((run / "metrics.json").read_text())["surface_diagnostics"]
    row = run_bias(run, {})
    assert row["smoky_pixels"] == recorded["smoky_pixels"] > 0
    np.testing.assert_allclose([row["bias_r"], row["bias_g"], row["bias_b"]], recorded["colour_bias_smoky"], atol=2e-3)
    out = tmp_path / "out" / "colour_bias"
    assert main(["--tables", str(tmp_path / "tables"), "--variants", "full", "--out", str(out)]) == 0
    assert out.with_suffix(".csv").is_file() and "| Ours (Full) | 0 | 1 |" in out.with_suffix(".md").read_text()


def test_the_cast_against_the_shadowed_frames_leaves_the_shadow_out(tmp_path: Path) -> None:
    """Shadowed frames 10 levels off the clean ones move the cast by 10/255 on every channel, the other
    way, and the summary shows both columns."""
    dataset = write_splat_dataset(tmp_path / "splat")
    run = tmp_path / "tables" / "runs" / "splat" / "full" / "seed0-x"
    assert train([str(dataset), "--out", str(run)] + TINY) == 0
    _as_harness_run(run, dataset)
    meta = json.loads((dataset / "dataset.json").read_text())
    meta["passes"]["rgb"].remove("shadowed")
    (dataset / "dataset.json").write_text(json.dumps(meta))
    without = run_bias(run, {})
    assert without["bias_shadowed_r"] == ""
    for clean in sorted((dataset / "rgb" / "clean").glob("*.png")):
        pixels = read_png(clean).astype(np.int16)
        assert pixels.max() <= 245, "the test needs clean frames with no value over the shift"
        write_png(dataset / "rgb" / "shadowed" / clean.name, (pixels + 10).astype(np.uint8))
    meta["passes"]["rgb"].append("shadowed")
    (dataset / "dataset.json").write_text(json.dumps(meta))
    row = run_bias(run, {})
    assert [row[f"bias_{c}"] for c in "rgb"] == [without[f"bias_{c}"] for c in "rgb"]
    np.testing.assert_allclose([row[f"bias_{c}"] - row[f"bias_shadowed_{c}"] for c in "rgb"], 10 / 255, atol=1e-4)
    out = tmp_path / "colour_bias"
    assert main(["--tables", str(tmp_path / "tables"), "--variants", "full", "--out", str(out)]) == 0
    text = out.with_suffix(".md").read_text()
    assert "| scene | Ours (Full) | Ours (Full), against shadowed |" in text
    summary = next(line for line in text.splitlines() if line.startswith("| Ours (Full), against shadowed | 0 | 1 |"))
    np.testing.assert_allclose([float(c) for c in summary.split("|")[4:7]], [row[f"bias_shadowed_{c}"] for c in "rgb"],
                               atol=1e-4)


def test_a_dataset_whose_masks_are_gone_is_one_line_naming_the_file(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    dataset = write_splat_dataset(tmp_path / "splat", smoke="none")
    for mask in (dataset / "rgb" / "smoke_mask").glob("*"):
        mask.unlink()
    (dataset / "rgb" / "smoke_mask").rmdir()
    run = tmp_path / "tables" / "runs" / "splat" / "full" / "seed0-x"
    (run / "renders" / "surface").mkdir(parents=True)
    (run / "train_log.csv").write_text("iteration\n")
    clean = sorted((dataset / "rgb" / "clean").glob("*.png"))[0]
    (run / "metrics.json").write_text(json.dumps({"per_image": [{"file_stem": clean.stem}]}))
    (run / "renders" / "surface" / clean.name).write_bytes(clean.read_bytes())
    _as_harness_run(run, dataset)
    assert main(["--tables", str(tmp_path / "tables"), "--variants", "full", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "smoke_mask/0000.png: missing file" in err
    assert not (tmp_path / "o.csv").exists()


def test_the_recoverable_cast_leaves_out_what_no_training_view_sees_through(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The recoverable columns are the cast on the masked test pixels outside the dataset's
    unrecoverable masks (contracts/unrecoverable.py), against the shadowed frames: computed here
    pixel by pixel from the renders and frames, and the summary gains the rows. A scene with no
    recoverable pixel has empty cells and share 0, never a NaN in the mean."""
    dataset = write_splat_dataset(tmp_path / "splat")
    run = tmp_path / "tables" / "runs" / "splat" / "full" / "seed0-x"
    assert train([str(dataset), "--out", str(run)] + TINY) == 0
    _as_harness_run(run, dataset)
    row = run_bias(run, {})
    reach = dataset_unrecoverable(dataset)
    rgb = load_scene(dataset).rgb
    index = {f.file_stem: i for i, f in enumerate(rgb.frames)}
    errors, masked = [], 0
    for stem, unreachable in reach.items():
        render = image01(read_png(run / "renders" / "surface" / f"{stem}.png")).astype(np.float64)
        smoky = rgb.masks[index[stem]] > 0.5
        masked += int(smoky.sum())
        errors.append(render[smoky & ~unreachable] - rgb.shadowed[index[stem]][smoky & ~unreachable])
    errors = np.concatenate(errors)
    assert 0 < len(errors) < masked, "the test needs masked pixels on both sides of the reach split"
    assert row["recoverable_against"] == "shadowed"
    assert row["recoverable_share"] == round(len(errors) / masked, 4)
    np.testing.assert_allclose([row[f"bias_recoverable_{c}"] for c in "rgb"], errors.mean(0), atol=1e-5)
    out = tmp_path / "colour_bias"
    assert main(["--tables", str(tmp_path / "tables"), "--variants", "full", "--out", str(out)]) == 0
    assert "| Ours (Full), recoverable pixels | 0 | 1 |" in out.with_suffix(".md").read_text()
    monkeypatch.setattr("benchmarks.colour_bias.reach_masks", lambda root: {k: np.ones_like(v) for k, v in reach.items()})
    none = run_bias(run, {})
    assert none["recoverable_share"] == 0.0 and [none[f"bias_recoverable_{c}"] for c in "rgb"] == ["", "", ""]
