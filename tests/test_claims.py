"""The claims check on fixture runs with known values: which seeds count, the verdicts, and the
numbers it quotes."""

from __future__ import annotations

import csv
from pathlib import Path

from eval.claims import ablation_checks, complete_seeds, input_psnr, method_checks, write_claims
from eval.runs import RunResult


def _run(scene: str, variant: str, seed: int, psnr: float, psnr_input: float, status: str = "ok") -> RunResult:
    return RunResult(scene, variant, seed, status, f"/nonexistent/{scene}/{variant}/{seed}", "h" * 64,
                     metrics={"psnr": psnr, "psnr_input": psnr_input} if status == "ok" else {})


INPUT = {"a": 20.0, "b": 10.0}
DEHAZED_INPUT = 5.0  # a dehazing baseline scores its dehazed frames: never the smoky input


def _table1(full: dict[tuple[str, int], float], rgb: dict[tuple[str, int], float],
            dcp: dict[tuple[str, int], float]) -> list[RunResult]:
    runs = [_run(s, "full", seed, v, INPUT[s]) for (s, seed), v in full.items()]
    runs += [_run(s, "rgb-only", seed, v, INPUT[s]) for (s, seed), v in rgb.items()]
    runs += [_run(s, "imgdehaze-dcp", seed, v, DEHAZED_INPUT) for (s, seed), v in dcp.items()]
    return runs


def test_input_floor_is_the_smoky_input_not_the_dehazed_one() -> None:
    runs = _table1({("a", 0): 21.0, ("b", 0): 12.0}, {}, {("a", 0): 8.0, ("b", 0): 6.0})
    assert input_psnr(runs) == INPUT


def test_incomplete_seed_is_left_out_and_named() -> None:
    full = {("a", 0): 22.0, ("b", 0): 12.0, ("a", 1): 24.0, ("b", 1): 14.0, ("a", 2): 99.0}
    rgb = {("a", 0): 21.0, ("b", 0): 11.0, ("a", 1): 21.0, ("b", 1): 11.0, ("a", 2): 0.0, ("b", 2): 0.0}
    runs = _table1(full, rgb, {})
    seeds, left_out = complete_seeds(runs, ("full", "rgb-only"))
    assert seeds == [0, 1] and left_out == "seed 2: 3 of 4 runs"
    order, above_mean, above_scenes = method_checks(runs)
    # Full: seed 0 mean 17, seed 1 mean 19 -> 18 ± 1.41; RGB-only 16 ± 0: seed 2's 99 and 0 ignored.
    assert order.holds == "yes" and order.seeds == "0, 1"
    assert "Ours (Full) 18.00 ± 1.41, Ours (RGB only) 16.00 ± 0.00 dB; ahead on 2 of 2 scenes" in order.measured
    # Input mean 15; Full 18 -> above. Per scene (mean over seeds): a 23 > 20, b 13 > 10.
    assert above_mean.holds == "yes" and "input 15.00" in above_mean.measured
    assert above_scenes.holds == "yes" and above_scenes.measured.startswith("2 of 2")


def test_order_fails_when_the_second_method_is_ahead_on_the_mean() -> None:
    # Full wins scene b by a little and loses scene a by a lot: ahead on 1 of 2, behind on the mean.
    full = {("a", 0): 20.0, ("b", 0): 11.0}
    rgb = {("a", 0): 25.0, ("b", 0): 10.5}
    dcp = {("a", 0): 26.0, ("b", 0): 1.0}
    order_full_rgb, order_rgb_dcp, above_mean, above_scenes = method_checks(_table1(full, rgb, dcp))
    assert order_full_rgb.holds == "no" and "ahead on 1 of 2 scenes" in order_full_rgb.measured
    assert order_rgb_dcp.holds == "yes"  # 17.75 against 13.5
    # Full 15.5 above the input mean 15, but 0.8 of 2 scenes rounds up to both, and a is below.
    assert above_mean.holds == "yes"
    assert above_scenes.holds == "no" and above_scenes.claim.startswith("Ours (Full) > smoky input on at least 2 of 2")
    assert above_scenes.measured == "1 of 2 (seed 0: 1)"


def test_no_complete_seed_reads_not_yet() -> None:
    runs = _table1({("a", 0): 22.0}, {("a", 0): 21.0, ("b", 0): 11.0}, {})
    runs.append(_run("b", "full", 0, 0.0, INPUT["b"], status="failed"))
    checks = method_checks(runs)
    assert [c.holds for c in checks] == ["not yet"] * 3
    assert all(c.left_out.startswith("seed 0:") for c in checks)


def test_ablation_above_full_fails_and_names_the_scene() -> None:
    runs = _table1({("a", 0): 20.0, ("b", 0): 12.0}, {}, {})
    runs += [_run("a", "no-mask", 0, 19.0, INPUT["a"]), _run("b", "no-mask", 0, 14.0, INPUT["b"])]
    runs += [_run("a", "no-mono", 0, 19.0, INPUT["a"]), _run("b", "no-mono", 0, 12.0, INPUT["b"])]
    no_mono, no_mask = ablation_checks(runs)
    assert no_mask.holds == "no" and "(+0.50); above Full on 1 of 2 scenes (b)" in no_mask.measured
    assert no_mono.holds == "yes" and "(-0.50); above Full on 0 of 2 scenes" in no_mono.measured


def test_written_files(tmp_path: Path) -> None:
    runs = _table1({("a", 0): 22.0, ("b", 0): 12.0}, {("a", 0): 21.0, ("b", 0): 11.0}, {})
    paths = write_claims(runs, tmp_path)
    rows = list(csv.DictReader(paths["claims.csv"].open()))
    assert [r["holds"] for r in rows] == ["yes", "yes", "yes"]
    md = paths["claims.md"].read_text()
    assert "| a | 20.00 | 22.00 | 21.00 |" in md and "| b | 10.00 | 12.00 | 11.00 |" in md
    assert "| Ours (Full) | 17.00 |" in md and "| smoky input | 15.00 |" in md


def test_per_seed_table_names_incomplete_seeds(tmp_path: Path) -> None:
    runs = _table1({("a", 0): 22.0, ("b", 0): 12.0, ("a", 1): 30.0}, {}, {})
    md = write_claims(runs, tmp_path)["claims.md"].read_text()
    assert "| Ours (Full) | 17.00 | (1 of 2 scenes) |" in md
