"""The shadow's share of the input's gap (benchmarks/shadow_share.py): the rows, the mean, and the refusal."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from benchmarks.shadow_share import share_rows


def _dataset(root: Path, name: str, views: dict) -> Path:
    d = root / name
    d.mkdir()
    (d / "dataset.json").write_text(json.dumps({"stats": {"test_views": views}}))
    return d


def test_the_mean_line_is_the_mean_of_the_datasets(tmp_path: Path) -> None:
    a = _dataset(tmp_path, "a", {"psnr_smoky_vs_clean": 20.0, "psnr_smoky_vs_shadowed": 21.0,
                                 "psnr_shadowed_vs_clean": 40.0})
    b = _dataset(tmp_path, "b", {"psnr_smoky_vs_clean": 30.0, "psnr_smoky_vs_shadowed": 30.5,
                                 "psnr_shadowed_vs_clean": 50.0})
    rows = share_rows([a, b])
    assert [r["dataset"] for r in rows] == ["a", "b", "mean"]
    assert rows[-1] == {"dataset": "mean", "psnr_smoky_vs_clean": 25.0, "psnr_smoky_vs_shadowed": 25.75,
                        "psnr_shadowed_vs_clean": 45.0}


def test_a_dataset_without_the_shadowed_figures_is_refused_by_name(tmp_path: Path) -> None:
    a = _dataset(tmp_path, "a", {"psnr_smoky_vs_clean": 20.0})
    with pytest.raises(SystemExit, match=r"a/dataset.json: stats.test_views.psnr_smoky_vs_shadowed is missing"):
        share_rows([a])


def test_the_committed_standard_figures_are_the_datasets_own(tmp_path: Path) -> None:
    """The committed CSV, where it exists, says what the committed datasets' statistics say."""
    root = Path(__file__).resolve().parents[1]
    committed = root / "benchmarks/results/standard/shadow_share.csv"
    if not committed.is_file():
        pytest.skip("no committed shadow_share.csv yet")
    rows = list(csv.DictReader(committed.open()))
    again = share_rows([root / "data/standard" / r["dataset"] for r in rows[:-1]])
    for r, s in zip(rows, again):
        assert r["dataset"] == s["dataset"]
        assert all(abs(float(r[c]) - s[c]) < 1e-9 for c in ("psnr_smoky_vs_clean", "psnr_smoky_vs_shadowed"))
