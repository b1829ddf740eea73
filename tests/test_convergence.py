"""The end-of-budget slopes on run folders with known validation curves."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from eval.convergence import iterations_to_close, run_convergence, write_convergence
from eval.runs import RunResult
from tests.results_builder import write_metrics

HEADER = ["stage", "iteration", "wall_s", "val_psnr", "test_psnr"]


def _run(tmp: Path, scene: str, variant: str, curve: list[tuple[int, int, float | None]],
         val_input: float = 20.0) -> RunResult:
    """A finished run folder whose train_log.csv holds (stage, iteration, val_psnr) rows."""
    folder = tmp / scene / variant
    write_metrics(folder, scene=scene, method=variant, profile="standard", seed=0,
                  validation={"views": 4, "psnr": curve[-1][2], "ssim": 0.5, "psnr_input": val_input})
    with open(folder / "train_log.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HEADER)
        for stage, it, v in curve:
            w.writerow([stage, it, it / 10, "" if v is None else v, ""])
    return RunResult(scene, variant, 0, "ok", str(folder), "h" * 64, metrics={"psnr": 0.0})


def _linear(end: float, slope_per_1000: float, last: int = 3000) -> list[tuple[int, int, float | None]]:
    """Stage 2 (never fitted), then a Stage-3 curve: flat early, then a line of the given slope
    over the last 1500 iterations, with unlogged rows between the validation points."""
    rows: list[tuple[int, int, float | None]] = [(2, 3000, 99.0)]
    for it in range(250, last + 1, 250):
        v = end - slope_per_1000 * max(0, last - max(it, last - 1500)) / 1000
        rows += [(3, it - 10, None), (3, it, v)]
    return rows


def test_slope_and_end_of_a_known_line(tmp_path: Path) -> None:
    c = run_convergence(_run(tmp_path, "a", "full", _linear(21.0, 0.8)))
    assert c.stage == 3 and c.last_iteration == 3000 and c.tail_points == 5  # 2000, 2250, ..., 3000
    assert c.val_psnr_end == 21.0 and c.slope_per_1000 == pytest.approx(0.8)
    assert c.val_psnr_input == 20.0


def test_a_resumed_attempts_repeated_rows_do_not_count(tmp_path: Path) -> None:
    first = [(3, it, 0.0) for it in (2000, 2250, 2500)]  # an attempt that was interrupted and redone
    run = _run(tmp_path, "a", "full", [*first, *[r for r in _linear(21.0, 0.8) if r[1] >= 1750]])
    assert run_convergence(run).slope_per_1000 == pytest.approx(0.8)


def test_iterations_to_close() -> None:
    assert iterations_to_close(-2.0, 0.5) == pytest.approx(4000)
    assert iterations_to_close(0.3, -1.0) == 0
    assert math.isinf(iterations_to_close(-1.0, 0.0)) and math.isinf(iterations_to_close(-1.0, -0.2))


def test_summary_gap_and_catch_up(tmp_path: Path) -> None:
    runs = [_run(tmp_path, "a", "full", _linear(20.0, 0.8)),  # 1.0 behind, gaining 0.6 faster
            _run(tmp_path, "a", "rgb-only", _linear(21.0, 0.2)),
            _run(tmp_path, "b", "full", _linear(22.0, 0.1), val_input=23.0),  # behind the input, barely rising
            _run(tmp_path, "b", "rgb-only", _linear(21.0, 0.5))]
    broken = RunResult("c", "full", 0, "ok", str(tmp_path / "nothing"), "h" * 64, metrics={"psnr": 0.0})
    paths = write_convergence([*runs, broken], tmp_path / "out")
    md = paths["convergence.md"].read_text()
    assert "| a | Ours (RGB only) | 1 | 21.00 | 0.20 | -1.00 | 1,667 |" in md
    assert "| a | smoky input | - | 20.00 | 0.00 | 0.00 | ahead |" in md
    assert "| b | Ours (RGB only) | 1 | 21.00 | 0.50 | 1.00 | ahead |" in md
    assert "| b | smoky input | - | 23.00 | 0.00 | -1.00 | 10,000 |" in md
    assert "c full seed 0:" in md and "train_log.csv: missing" in md
    # mean over scenes: Full 21.00 rising 0.45, RGB-only 21.00 rising 0.35, input 21.50
    assert "| Ours (RGB only) | 2 | 21.00 | 0.35 | 21.00 / 0.45 | 0.00 | ahead |" in md
    assert "| smoky input | 2 | 21.50 | 0.00 | 21.00 / 0.45 | -0.50 | 1,111 |" in md
    assert len(list(csv.DictReader(paths["convergence.csv"].open()))) == 4
