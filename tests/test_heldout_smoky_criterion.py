"""The held-out criterion's CSV keeps other runs' rows and replaces the same run's."""
from __future__ import annotations

import csv
from pathlib import Path

from benchmarks.heldout_smoky_criterion import merge_rows


def _rows(scene: str, seed: int, psnr: float) -> list[dict[str, object]]:
    return [{"scene": scene, "mode": "full", "seed": seed, "iteration": it, "val_clean_psnr": psnr,
             "val_smoky_psnr": psnr + 5, "test_psnr": psnr} for it in (250, 500)]


def test_a_run_replaces_its_own_rows_and_keeps_the_others(tmp_path: Path) -> None:
    target = tmp_path / "criterion.csv"
    merge_rows(target, _rows("excavator", 0, 20.0))
    merge_rows(target, _rows("room", 0, 12.0))
    merge_rows(target, _rows("excavator", 0, 21.0))
    got = list(csv.DictReader(open(target)))
    assert [(r["scene"], float(r["test_psnr"])) for r in got] == [("room", 12.0)] * 2 + [("excavator", 21.0)] * 2
    merge_rows(target, _rows("excavator", 1, 19.0))
    assert len(list(csv.DictReader(open(target)))) == 6
