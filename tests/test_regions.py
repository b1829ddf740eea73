"""The region split of eval/regions.py against hand-computed PSNRs on tiny images."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from contracts.errors import DatasetError
from contracts.imageio import read_png, write_png
from eval.regions import BANDS, score_run, write_region_split
from eval.runs import RunResult

H, W = 4, 6


def _rgb(level: int) -> np.ndarray:
    return np.full((H, W, 3), level, np.uint8)


def _scene(root: Path, masks: dict[str, np.ndarray], smoky_offset: int) -> None:
    """Clean frames at 100; the smoky input is +smoky_offset on smoky pixels, exact elsewhere."""
    for stem, mask in masks.items():
        clean = _rgb(100)
        smoky = clean.copy()
        smoky[mask] += np.uint8(smoky_offset)
        write_png(root / "rgb" / "clean" / f"{stem}.png", clean)
        write_png(root / "rgb" / "smoky" / f"{stem}.png", smoky)
        write_png(root / "rgb" / "smoke_mask" / f"{stem}.png", np.where(mask, 255, 0).astype(np.uint8))


def _run(root: Path, renders: dict[str, np.ndarray], scene: str = "s", variant: str = "full") -> RunResult:
    for stem, img in renders.items():
        write_png(root / "renders" / "surface" / f"{stem}.png", img)
    return RunResult(scene, variant, 0, "ok", str(root), "hash")


def _db(err_levels: float) -> float:
    return 10 * math.log10(1 / (err_levels / 255) ** 2)


def test_pooled_psnr_per_region(tmp_path: Path) -> None:
    left = np.zeros((H, W), bool)
    left[:, :2] = True  # view 0000: 8 of 24 pixels smoky
    half = np.zeros((H, W), bool)
    half[:, :3] = True  # view 0008: 12 of 24 pixels smoky
    _scene(tmp_path / "ds", {"0000": left, "0008": half}, smoky_offset=30)
    # The method is 10 levels off on smoky pixels and 4 off on clear pixels of both views.
    renders = {}
    for stem, mask in (("0000", left), ("0008", half)):
        img = _rgb(104)
        img[mask] = 110
        renders[stem] = img
    scores = {s.region: s for s in score_run(_run(tmp_path / "run", renders), tmp_path / "ds")}
    assert scores["smoky"].pixel_share == pytest.approx(20 / 48)
    assert scores["smoky"].psnr == pytest.approx(_db(10))
    assert scores["smoky"].psnr_input == pytest.approx(_db(30))
    assert scores["clear"].psnr == pytest.approx(_db(4))
    assert scores["clear"].psnr_input == pytest.approx(100.0)  # exact input: the metrics' cap
    smoky_err, clear_err = 20 * 10 ** 2, 28 * 4 ** 2
    assert scores["clear"].error_share == pytest.approx(clear_err / (smoky_err + clear_err))
    assert scores["smoky"].views == 2


def test_smoke_free_region_is_nan_not_an_error(tmp_path: Path) -> None:
    everywhere = np.ones((H, W), bool)
    _scene(tmp_path / "ds", {"0000": everywhere}, smoky_offset=20)
    scores = {s.region: s for s in score_run(_run(tmp_path / "run", {"0000": _rgb(100)}), tmp_path / "ds")}
    assert math.isnan(scores["clear"].psnr) and scores["clear"].pixel_share == 0
    assert scores["smoky"].psnr == pytest.approx(100.0)
    assert scores["smoky"].psnr_input == pytest.approx(_db(20))


def test_missing_file_and_missing_mask_are_named_and_skipped(tmp_path: Path) -> None:
    mask = np.zeros((H, W), bool)
    _scene(tmp_path / "ds", {"0000": mask}, smoky_offset=0)
    (tmp_path / "ds" / "rgb" / "clean" / "0000.png").unlink()
    run = _run(tmp_path / "run", {"0000": _rgb(100)})
    with pytest.raises(DatasetError, match=r"rgb/clean/0000\.png: missing file"):
        score_run(run, tmp_path / "ds")
    capture = tmp_path / "capture"
    (capture / "rgb" / "clean").mkdir(parents=True)
    other = _run(tmp_path / "run2", {"0000": _rgb(100)}, scene="real")
    paths = write_region_split([run, other], {"s": tmp_path / "ds", "real": capture}, tmp_path / "out")
    md = paths["per_scene_regions.md"].read_text()
    assert "s full seed 0:" in md and "missing file" in md
    assert "real full seed 0:" in md and "no smoke ground truth" in md
    with open(paths["per_scene_regions.csv"], newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows == []


def test_written_table_rows(tmp_path: Path) -> None:
    mask = np.zeros((H, W), bool)
    mask[0] = True
    _scene(tmp_path / "ds", {"0000": mask}, smoky_offset=40)
    img = _rgb(100)
    img[mask] = 120
    paths = write_region_split([_run(tmp_path / "run", {"0000": img})], {"s": tmp_path / "ds"}, tmp_path / "out")
    with open(paths["per_scene_regions.csv"], newline="") as f:
        rows = {r["region"]: r for r in csv.DictReader(f)}
    assert float(rows["smoky"]["psnr"]) == pytest.approx(_db(20))
    assert float(rows["smoky"]["psnr_input"]) == pytest.approx(_db(40))
    assert "| s | Ours (Full) | 1 | 25 % | 22.11 / 16.09 |" in paths["per_scene_regions.md"].read_text()


def test_run_at_reduced_width_is_compared_at_its_size(tmp_path: Path) -> None:
    mask = np.zeros((H, W), bool)
    mask[:2] = True  # top half smoky: whole 2x2 blocks
    _scene(tmp_path / "ds", {"0000": mask}, smoky_offset=30)
    img = np.full((H // 2, W // 2, 3), 105, np.uint8)
    img[:1] = 100
    scores = {s.region: s for s in score_run(_run(tmp_path / "run", {"0000": img}), tmp_path / "ds")}
    assert scores["smoky"].pixel_share == pytest.approx(0.5)
    assert scores["smoky"].psnr == pytest.approx(100.0)
    assert scores["clear"].psnr == pytest.approx(_db(5))
    odd = _run(tmp_path / "run_odd", {"0000": np.zeros((3, 5, 3), np.uint8)})
    with pytest.raises(DatasetError, match="downscaled by a whole factor"):
        score_run(odd, tmp_path / "ds")


def test_bands_by_how_much_the_smoke_changes_a_pixel(tmp_path: Path) -> None:
    """Columns changed by 0, 5, 6, 13, 26 and 60 levels fall in the bands below 0.02 (0 and 5/255),
    0.02-0.05 (6/255), 0.05-0.1 (13/255), 0.1-0.2 (26/255) and over 0.2 (60/255); the method is
    off by 3 levels everywhere except the 0.1-0.2 column, where it is exact."""
    clean = _rgb(100)
    smoky = clean.copy()
    for col, change in enumerate((0, 5, 6, 13, 26, 60)):
        smoky[:, col, 1] += np.uint8(change)  # one channel: the band goes by the largest
    write_png(tmp_path / "ds" / "rgb" / "clean" / "0000.png", clean)
    write_png(tmp_path / "ds" / "rgb" / "smoky" / "0000.png", smoky)
    write_png(tmp_path / "ds" / "rgb" / "smoke_mask" / "0000.png", np.zeros((H, W), np.uint8))
    render = _rgb(103)
    render[:, 4] = 100
    scores = {s.region: s for s in score_run(_run(tmp_path / "run", {"0000": render}), tmp_path / "ds")}
    share = {b: scores[b].pixel_share for b in BANDS}
    assert share == pytest.approx({BANDS[0]: 2 / 6, BANDS[1]: 1 / 6, BANDS[2]: 1 / 6, BANDS[3]: 1 / 6, BANDS[4]: 1 / 6})
    assert scores[BANDS[0]].psnr_input == pytest.approx(10 * math.log10(3 * 2 / (25 / 255 ** 2)))
    assert scores[BANDS[4]].psnr_input == pytest.approx(10 * math.log10(3 / (60 / 255) ** 2))
    assert scores[BANDS[1]].psnr == pytest.approx(_db(3)) and scores[BANDS[3]].psnr == pytest.approx(100.0)
    assert scores[BANDS[3]].error_share == 0.0
    assert sum(scores[b].error_share for b in BANDS) == pytest.approx(1.0)
    md = write_region_split([_run(tmp_path / "run", {"0000": render})], {"s": tmp_path / "ds"}, tmp_path / "out")
    text = md["per_scene_regions.md"].read_text()
    assert "## By how much the smoke changes a pixel" in text
    assert "| change 0-0.02 | change 0.02-0.05 | change 0.05-0.1 | change 0.1-0.2 | change 0.2+ |" in text
    assert "| s | Ours (Full) | 1 | 38.6 / 41.9 (33 %) | 38.6 / 37.3 (17 %) | 38.6 / 30.6 (17 %) | 100.0 / 24.6 (17 %) |" in text


def test_reach_split_and_scores_against_shadowed(tmp_path: Path) -> None:
    """The unrecoverable pixels (given masks: their computation is tested in test_dataset_stats)
    and the rest pool separately; with shadowed frames every region is scored against them too.
    Clean at 100 everywhere, shadowed at 90 in the left half (the shadow), the smoky input at 90
    there too (the smoke's shadow and no smoke in view); the method renders 100 everywhere but
    110 on the two unrecoverable columns."""
    mask = np.zeros((H, W), bool)
    _scene(tmp_path / "ds", {"0000": mask}, smoky_offset=0)
    shadowed = _rgb(100)
    shadowed[:, :3] = 90
    write_png(tmp_path / "ds" / "rgb" / "smoky" / "0000.png", shadowed)
    write_png(tmp_path / "ds" / "rgb" / "shadowed" / "0000.png", shadowed)
    out_of_reach = np.zeros((H, W), bool)
    out_of_reach[:, 4:] = True
    render = _rgb(100)
    render[out_of_reach] = 110
    run = _run(tmp_path / "run", {"0000": render})
    scores = {s.region: s for s in score_run(run, tmp_path / "ds", {"0000": out_of_reach})}
    assert scores["unrecoverable"].pixel_share == pytest.approx(2 / 6)
    assert scores["unrecoverable"].psnr == pytest.approx(_db(10))
    assert scores["recoverable"].psnr == pytest.approx(100.0)
    # The input against clean is off by the shadow on half the pixels, against shadowed not at all.
    assert scores["all"].psnr_input == pytest.approx(10 * math.log10(2 / (10 / 255) ** 2))
    assert scores["all"].psnr_input_shadowed == pytest.approx(100.0)
    assert scores["clear"].psnr_shadowed == pytest.approx(10 * math.log10(6 / (3 * 10 ** 2 + 2 * 10 ** 2) * 255 ** 2))
    plain = {s.region: s for s in score_run(run, tmp_path / "ds")}
    assert "unrecoverable" not in plain and set(plain) == set(scores) - {"unrecoverable", "recoverable"}
    text = write_region_split([run], {"s": tmp_path / "ds"}, tmp_path / "out")["per_scene_regions.md"].read_text()
    assert "## Against the shadowed ground truth" in text and "## Out of reach" not in text  # no depth: no reach split
    assert "| s | Ours (Full) | 1 | 32.90 / 28.92 | 31.14 / 100.00 | 31.14 / 100.00 |" in text


def test_reach_split_of_a_dataset_with_depth_and_smoke(tmp_path: Path) -> None:
    """A dataset with cameras, depth and smoke opacity gets the reach split from its own files."""
    from contracts.unrecoverable import dataset_unrecoverable
    from tests.test_smokeseer_data import write_splat_dataset

    ds = write_splat_dataset(tmp_path / "ds", n_rgb=8, n_thermal=3, smoke="opaque")
    masks = dataset_unrecoverable(ds)
    assert sorted(masks) == ["0002", "0006"] and all(0.0 < m.mean() < 1.0 for m in masks.values())
    run = _run(tmp_path / "run", {s: read_png(ds / "rgb" / "clean" / f"{s}.png") for s in masks})
    paths = write_region_split([run], {"s": ds}, tmp_path / "out")
    assert "## Out of reach of the RGB frames" in paths["per_scene_regions.md"].read_text()
    with open(paths["per_scene_regions.csv"], newline="") as f:
        rows = {r["region"]: r for r in csv.DictReader(f)}
    share = np.mean([m.mean() for m in masks.values()])
    assert float(rows["unrecoverable"]["pixel_share"]) == pytest.approx(share)
    assert float(rows["unrecoverable"]["psnr"]) == pytest.approx(100.0)  # the render is the clean frame
