"""The rule that gives a Table 2 ablation seeds 1-2: seed-0 mean within 0.3 dB of Full's, or above."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from eval.reseed_ablations import RESEED_MARGIN_DB, ablations_to_reseed, main
from tests.results_builder import write_metrics

DIGEST = "f" * 64
SCENES = ["a", "b"]


def _run(tables: Path, scene: str, variant: str, psnr: float, seed: int = 0, digest: str = DIGEST,
         status: str = "ok", stages: dict | None = None) -> None:
    folder = tables / "runs" / scene / variant / f"seed{seed}-{digest[:12]}"
    folder.mkdir(parents=True)
    (folder / "train_log.csv").write_text("stage,iteration\n")
    write_metrics(folder, scene=scene, method=variant, profile="standard", seed=seed, status=status,
                  metrics={"psnr": psnr}, stages=stages or {})
    (folder / "harness.json").write_text(json.dumps({
        "scene": scene, "variant": variant, "seed": seed, "status": status, "code_digest": digest,
        "metrics": {"psnr": psnr}}))


@pytest.fixture
def tables(tmp_path: Path) -> Path:
    out = tmp_path / "tables"
    for scene, psnr in zip(SCENES, (20.0, 30.0)):  # Full's mean: 25.0
        _run(out, scene, "full", psnr)
    return out


def test_an_ablation_close_below_full_or_above_it_is_reseeded_and_one_well_below_is_not(tables: Path) -> None:
    for scene, psnr in zip(SCENES, (20.0, 30.0 - 2 * (RESEED_MARGIN_DB - 0.05))):  # mean 25 - margin + 0.05
        _run(tables, scene, "close", psnr)
    for scene, psnr in zip(SCENES, (20.0, 30.0 - 2 * (RESEED_MARGIN_DB + 0.05))):  # mean 25 - margin - 0.05
        _run(tables, scene, "below", psnr)
    for scene, psnr in zip(SCENES, (21.0, 31.0)):
        _run(tables, scene, "above", psnr)
    assert ablations_to_reseed(tables, SCENES, ["below", "above", "close"], DIGEST) == ["above", "close"]


def test_only_finished_seed0_runs_of_the_trainer_asked_for_count(tables: Path) -> None:
    _run(tables, "a", "partial", 25.0)  # b not finished: the row is not decided yet
    _run(tables, "b", "partial", 25.0, status="failed")
    _run(tables, "a", "other-trainer", 25.0, digest="0" * 64)
    _run(tables, "b", "other-trainer", 25.0, digest="0" * 64)
    _run(tables, "a", "seed1-only", 25.0, seed=1)
    _run(tables, "b", "seed1-only", 25.0, seed=1)
    assert ablations_to_reseed(tables, SCENES, ["partial", "other-trainer", "seed1-only"], DIGEST) == []


def test_a_scene_where_fulls_run_stands_for_the_ablation_counts_with_fulls_score(tmp_path: Path) -> None:
    """The harness never trains a twin (eval/twins.py), so no run folder of the ablation is there:
    on scene b Full held the smoke colour fixed, so no-mono and no-smoke-color score Full's 30 dB."""
    tables = tmp_path / "t"
    _run(tables, "a", "full", 20.0)
    _run(tables, "b", "full", 30.0, stages={"smoke_colour": {"source": "haze-lines"}})
    _run(tables, "a", "no-mono", 21.0)  # mean with b's twin 25.5: above Full's 25
    _run(tables, "a", "no-smoke-color", 18.0)  # mean 24.0: more than the margin below
    _run(tables, "a", "no-mask", 21.0)  # no twin of Full for this ablation: b is not finished
    assert ablations_to_reseed(tables, SCENES, ["no-mono", "no-smoke-color", "no-mask"], DIGEST) == ["no-mono"]
    _run(tables, "b", "no-mono", 10.0)  # a trained run, where there is one, is what counts
    assert ablations_to_reseed(tables, SCENES, ["no-mono"], DIGEST) == []


def test_without_full_at_seed0_nothing_is_reseeded(tmp_path: Path) -> None:
    for scene in SCENES:
        _run(tmp_path / "t", scene, "close", 25.0)
    assert ablations_to_reseed(tmp_path / "t", SCENES, ["close"], DIGEST) == []
    assert ablations_to_reseed(tmp_path / "empty", SCENES, ["close"], DIGEST) == []


def test_the_command_prints_one_ablation_per_line(tables: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for scene, psnr in zip(SCENES, (20.0, 30.0)):
        _run(tables, scene, "no-mono", psnr)
    assert main([str(tables), "--scenes", ",".join(SCENES), "--digest", "fff"]) == 0
    assert capsys.readouterr().out == "no-mono\n"
    assert main([str(tables), "--scenes", ","]) == 2


def test_a_full_run_whose_metrics_break_the_contract_is_one_clear_error(tables: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    broken = next((tables / "runs" / "b" / "full").iterdir()) / "metrics.json"
    broken.write_text(json.dumps({"format": "smokeseer-synth-results"}))
    assert main([str(tables), "--scenes", ",".join(SCENES), "--digest", "fff"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{broken}: missing field" in err
