"""eval/per_view.py against hand-computed view counts and pooled PSNRs."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from eval.per_view import mean_of_all, pooled_over_views, summarise, view_scores, write_per_view
from eval.runs import RunResult
from eval.tables import RESCORED_LPIPS
from tests.results_builder import write_metrics


def _run(root: Path, variant: str, seed: int, views: dict[str, tuple[float, float]], scene: str = "s",
         lpips: dict[str, float] | None = None) -> RunResult:
    """A finished run whose metrics.json lists (psnr, psnr_input) per test view, and ``lpips`` for the views given."""
    folder = root / scene / variant / f"seed{seed}"
    per_image = [{"file_stem": stem, "psnr": p, "ssim": 0.5, "psnr_input": q,
                  **({"lpips": lpips[stem]} if lpips and stem in lpips else {})} for stem, (p, q) in views.items()]
    write_metrics(folder, scene=scene, method=variant, profile="quick", seed=seed,
                  metrics={"psnr": sum(p for p, _ in views.values()) / len(views)}, per_image=per_image)
    return RunResult(scene, variant, seed, "ok", str(folder), "hash")


def test_pooled_over_views_weighs_the_worst_view() -> None:
    # MSEs 0.1 and 0.001: the mean of PSNRs is 20 dB, the pooled PSNR that of MSE 0.0505.
    assert pooled_over_views([10.0, 30.0]) == pytest.approx(-10 * math.log10(0.0505))
    assert pooled_over_views([25.0, 25.0]) == pytest.approx(25.0)
    assert math.isnan(pooled_over_views([]))


def test_views_counted_against_input_and_full_at_the_same_seed(tmp_path: Path) -> None:
    # Full de-smokes the hidden view (input 10 dB) and is softer on the clear one (input 35 dB).
    full = _run(tmp_path, "full", 0, {"0004": (18.0, 10.0), "0036": (25.0, 35.0)})
    rgb = _run(tmp_path, "rgb-only", 0, {"0004": (12.0, 10.0), "0036": (33.0, 35.0)})
    rgb_seed1 = _run(tmp_path, "rgb-only", 1, {"0004": (40.0, 10.0), "0036": (40.0, 35.0)})  # no Full seed 1
    scores = view_scores([full, rgb, rgb_seed1])
    m_full, m_rgb = summarise(scores, "s", "full"), summarise(scores, "s", "rgb-only")
    assert m_full.mean_of_views == pytest.approx(21.5) and m_rgb.mean_of_views == pytest.approx((22.5 + 40) / 2)
    assert m_full.pooled == pytest.approx(pooled_over_views([18.0, 25.0]))
    assert m_full.above_input == 1 and m_full.above_reference is None
    # RGB-only beats the input on 0004 at seed 0 and on both views at seed 1; beats Full on 0036 only,
    # and seed 1 has no Full run to be paired with.
    assert (m_rgb.above_input, m_rgb.views) == (3, 4)
    assert (m_rgb.above_reference, m_rgb.paired_views) == (1, 2)
    assert m_full.input_mean_of_views == pytest.approx(22.5)
    # The mean of views ranks RGB-only's seed 0 first (22.5 > 21.5); pooling ranks Full first.
    assert pooled_over_views([18.0, 25.0]) > pooled_over_views([12.0, 33.0])


def test_dehazing_baseline_is_floored_by_the_smoky_input(tmp_path: Path) -> None:
    full = _run(tmp_path, "full", 0, {"0004": (18.0, 10.0)})
    dcp = _run(tmp_path, "imgdehaze-dcp", 0, {"0004": (14.0, 16.0)})  # its own input: the dehazed frame
    scores = {s.variant: s for s in view_scores([dcp, full])}
    assert scores["imgdehaze-dcp"].psnr_input == 10.0
    assert summarise(list(scores.values()), "s", "imgdehaze-dcp").above_input == 1


def test_files_written_and_failed_runs_left_out(tmp_path: Path) -> None:
    full = _run(tmp_path, "full", 0, {"0004": (18.0, 10.0), "0036": (25.0, 35.0)})
    failed = RunResult("s", "rgb-only", 0, "failed", str(tmp_path / "nowhere"), "hash", error="diverged")
    paths = write_per_view([full, failed], tmp_path / "out")
    rows = list(csv.DictReader(open(paths["per_view.csv"])))
    assert [(r["variant"], r["view"]) for r in rows] == [("full", "0004"), ("full", "0036")]
    md = paths["per_view.md"].read_text()
    assert "| s | Ours (Full) | 1 | 21.50 |" in md and "Ours (RGB only)" not in md and "Left out" not in md


def test_unreadable_metrics_is_named_not_raised(tmp_path: Path) -> None:
    full = _run(tmp_path, "full", 0, {"0004": (18.0, 10.0)})
    broken = _run(tmp_path, "rgb-only", 0, {"0004": (12.0, 10.0)})
    (Path(broken.run_dir) / "metrics.json").write_text("{")
    md = write_per_view([full, broken], tmp_path / "out")["per_view.md"].read_text()
    assert "Left out" in md and "rgb-only seed 0" in md and "metrics.json: not valid JSON" in md


def test_each_views_lpips_beside_its_psnr_and_no_mean_over_part_of_the_views(tmp_path: Path) -> None:
    how = f"{RESCORED_LPIPS} by benchmarks/rescore_lpips.py, alex"
    full = _run(tmp_path, "full", 0, {"0004": (18.0, 10.0), "0036": (25.0, 35.0)}, lpips={"0004": 0.3, "0036": 0.1})
    full1 = _run(tmp_path, "full", 1, {"0004": (18.0, 10.0), "0036": (25.0, 35.0)}, lpips={"0004": 0.5, "0036": 0.3})
    rgb = _run(tmp_path, "rgb-only", 0, {"0004": (12.0, 10.0), "0036": (33.0, 35.0)}, lpips={"0004": 0.6})
    full.metrics["lpips_status"] = full1.metrics["lpips_status"] = how
    scores = view_scores([full, full1, rgb])
    assert [(s.view, s.lpips) for s in scores if s.variant == "rgb-only"] == [("0004", 0.6), ("0036", None)]
    assert summarise(scores, "s", "full").lpips == pytest.approx((0.2 + 0.4) / 2)  # views, then seeds
    assert math.isnan(summarise(scores, "s", "rgb-only").lpips)  # one view unscored: no mean of the other alone
    assert math.isnan(mean_of_all([])) and mean_of_all([0.2, 0.4]) == pytest.approx(0.3)
    paths = write_per_view([full, full1, rgb], tmp_path / "out")
    rows = list(csv.DictReader(open(paths["per_view.csv"])))
    assert [r["lpips"] for r in rows] == ["0.3", "0.1", "0.5", "0.3", "0.6", ""]
    md = paths["per_view.md"].read_text()
    assert "| s | Ours (Full) | 2 | 21.50 |" in md and md.count("| 0.300 |") == 2  # the scene's row and the mean
    assert "| s | Ours (RGB only) | 1 |" in md and "| 1/2 | - |\n" in md
    assert f"- LPIPS: {how}, in 2 of the 3 runs; scored after training" in md
