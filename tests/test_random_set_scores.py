"""Full against RGB-only on a drawn set (benchmarks/random_set_scores.py): pairing, the counts the
must-holds read, the split, and its refusals."""
from __future__ import annotations

import csv
import json
import shutil
import subprocess
from pathlib import Path

import pytest

from benchmarks.random_set_scores import main


def _run(tables: Path, scene: str, variant: str, psnr: float, val: float | None, psnr_input: float = 20.0,
         seed: int = 0, float_setup: str = "") -> None:
    run = tables / "runs" / scene / variant / f"seed{seed}-x"
    run.mkdir(parents=True)
    (run / "train_log.csv").write_text("iteration\n")
    validation = {"psnr": val, "psnr_input": psnr_input - 1.0} if val is not None else None
    (run / "metrics.json").write_text(json.dumps({"validation": validation}))
    (run / "harness.json").write_text(json.dumps(
        {"scene": scene, "variant": variant, "seed": seed, "status": "ok", "code_digest": "c" * 64,
         "metrics": {"psnr": psnr, "psnr_input": psnr_input}, "float_setup": float_setup}))


def _dataset(datasets: Path, scene: str, depth: float) -> None:
    (datasets / scene).mkdir(parents=True)
    (datasets / scene / "dataset.json").write_text(json.dumps({"smoke": {"optical_depth": {"achieved": depth}}}))


def test_scenes_are_paired_and_the_must_hold_counts_are_printed(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    tables, datasets = tmp_path / "tables", tmp_path / "sets"
    for scene, depth, full, rgb in (("random_1", 0.2, 21.0, 21.2), ("random_2", 1.5, 19.0, 16.0),
                                    ("random_3", 2.5, 18.0, 18.5), ("random_4", 0.5, 25.0, 24.0)):
        _dataset(datasets, scene, depth)
        _run(tables, scene, "full", full, full - 2.0)
        _run(tables, scene, "rgb-only", rgb, rgb - 2.0)
    _run(tables, "random_5", "full", 30.0, 29.0)  # RGB-only not trained: no row
    _run(tables, "random_1", "full", 99.0, 99.0, seed=1)  # another seed: not read
    out = tmp_path / "per_scene.csv"
    assert main(["--tables", str(tables), "--datasets", str(datasets), "--out", str(out)]) == 0
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0])[:5] == ["scene", "rgb_optical_depth", "input_psnr", "full_psnr", "rgb_only_psnr"]
    assert [(r["scene"], float(r["full_minus_rgb_only"])) for r in rows] == [
        ("random_1", -0.2), ("random_2", 3.0), ("random_3", -0.5), ("random_4", 1.0)]
    line = capsys.readouterr().out
    assert "4 scenes" in line and "full: mean 20.75 dB; within 0.3 dB of RGB-only or better on 3" in line
    assert "+1.25 dB on the 2 scenes at optical depth >= 1" in line and "over the smoky input on 2" in line
    assert main(["--tables", str(tables), "--datasets", str(datasets), "--out", str(out), "--split", "val"]) == 0
    assert "over the smoky input on 1" in capsys.readouterr().out  # validation: input 19; Full 19, 17, 16, 23


def test_candidates_are_counted_in_fulls_place_and_against_full(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A rule candidate gets its column and the same counts, plus its paired difference from Full; a
    scene where a candidate has not finished has no row, one without RGB-only has one (the counts
    against RGB-only leave it out and say so)."""
    tables, datasets = tmp_path / "tables", tmp_path / "sets"
    for scene, depth, full, rgb, cand in (("random_1", 0.2, 21.0, 21.2, 21.5), ("random_2", 1.5, 19.0, 16.0, 20.0),
                                          ("random_3", 2.5, 18.0, 18.5, 20.5)):
        _dataset(datasets, scene, depth)
        _run(tables, scene, "full", full, full - 2.0)
        _run(tables, scene, "rgb-only", rgb, rgb - 2.0)
        _run(tables, scene, "start-thermal", cand, cand - 2.0)
    _dataset(datasets, "random_4", 0.5)
    _run(tables, "random_4", "full", 25.0, 23.0)
    _run(tables, "random_4", "rgb-only", 24.0, 22.0)
    out, summary = tmp_path / "per_scene.csv", tmp_path / "summary.csv"
    assert main(["--tables", str(tables), "--datasets", str(datasets), "--out", str(out),
                 "--candidates", "start-thermal", "--summary", str(summary)]) == 0
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert [(r["scene"], float(r["start_thermal_psnr"])) for r in rows] == [
        ("random_1", 21.5), ("random_2", 20.0), ("random_3", 20.5)]
    text = capsys.readouterr().out
    assert "start-thermal: mean 20.67 dB; within 0.3 dB of RGB-only or better on 3" in text
    assert "+3.00 dB on the 2 scenes at optical depth >= 1" in text   # (4.0 + 2.0) / 2
    assert "- Full +1.33 ± 1.04 dB, ahead on 3 of 3" in text          # 0.5, 1.0, 2.5
    with open(summary) as f:
        assert [r["rule"] for r in csv.DictReader(f)] == ["full", "start-thermal"]
    _dataset(datasets, "random_5", 1.2)  # Full and the candidate, no RGB-only: a row, left out of those counts
    _run(tables, "random_5", "full", 20.0, 18.0)
    _run(tables, "random_5", "start-thermal", 19.0, 17.0)
    assert main(["--tables", str(tables), "--datasets", str(datasets), "--out", str(out),
                 "--candidates", "start-thermal"]) == 0
    with open(out) as f:
        last = list(csv.DictReader(f))[-1]
    assert (last["scene"], last["rgb_only_psnr"], last["start_thermal_psnr"]) == ("random_5", "", "19.0")
    text = capsys.readouterr().out
    assert "4 scenes" in text and "(RGB-only trained on 3 of them)" in text
    assert "+3.00 dB on the 2 scenes at optical depth >= 1" in text   # random_5 has no pair
    assert "- Full +0.75 ± 1.44 dB, ahead on 3 of 4" in text          # 0.5, 1.0, 2.5, -1.0
    shutil.rmtree(tables / "runs" / "random_1" / "rgb-only")
    shutil.rmtree(tables / "runs" / "random_2" / "rgb-only")
    shutil.rmtree(tables / "runs" / "random_3" / "rgb-only")
    assert main(["--tables", str(tables), "--datasets", str(datasets), "--out", str(out),
                 "--candidates", "start-thermal"]) == 0
    assert "start-thermal: mean 20.25 dB; RGB-only not trained; over the smoky input on" in capsys.readouterr().out


INTEL = ("cpu Intel(R) Xeon(R) Processor (avx avx2 avx512f fma); torch 2.13.0+cpu AVX512; held none; "
         "kernel -mavx2 -mfma; compiler c++ 12.2.0")
AMD = "cpu AMD EPYC (avx avx2 fma); torch 2.13.0+cpu AVX2; held none; kernel -mavx2 -mfma; compiler c++ 12.2.0"


def test_runs_from_two_machines_are_named_and_counted(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A scene whose Full and candidate ran on different CPUs says so: the pair's difference carries
    their rounding too."""
    tables, datasets = tmp_path / "tables", tmp_path / "sets"
    for scene, cand_setup in (("random_1", INTEL), ("random_2", AMD)):
        _dataset(datasets, scene, 0.5)
        _run(tables, scene, "full", 21.0, 20.0, float_setup=INTEL)
        _run(tables, scene, "start-thermal", 22.0, 21.0, float_setup=cand_setup)
    out = tmp_path / "per_scene.csv"
    assert main(["--tables", str(tables), "--datasets", str(datasets), "--out", str(out),
                 "--candidates", "start-thermal"]) == 0
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert [r["float_setups"] for r in rows] == ["1", "2"]
    assert rows[1]["machines"] == ("full: Intel(R) Xeon(R) Processor AVX512; "
                                   "start-thermal: AMD EPYC AVX2")
    assert "2 scenes, 1 of them with runs from more than one float setup" in capsys.readouterr().out


def test_runs_without_validation_views_or_pairs_are_one_line(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    tables, datasets = tmp_path / "tables", tmp_path / "sets"
    _dataset(datasets, "random_1", 1.0)
    _run(tables, "random_1", "full", 21.0, None)
    _run(tables, "random_1", "rgb-only", 20.0, None)
    out = tmp_path / "per_scene.csv"
    assert main(["--tables", str(tables), "--datasets", str(datasets), "--out", str(out), "--split", "val"]) == 2
    assert "validation: no validation views" in capsys.readouterr().err
    assert main(["--tables", str(tables), "--datasets", str(datasets), "--out", str(out), "--seed", "3"]) == 2
    assert "no scene has finished Full and RGB-only runs at seed 3" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.blender
def test_the_set_script_plans_both_methods_on_every_finished_scene(demo_dataset: Path, tmp_path: Path) -> None:
    """benchmarks/random_set_tables.sh trains Full and RGB-only at seed 0 on the set's finished scenes only
    (a staging folder and other folders are left out)."""
    root = Path(__file__).resolve().parents[1]
    sets = tmp_path / "random_dev"
    for name in ("random_7", "random_3"):
        shutil.copytree(demo_dataset, sets / name)
    (sets / ".random_9.partial").mkdir()
    (sets / "notes").mkdir()
    done = subprocess.run(["bash", "benchmarks/random_set_tables.sh", str(sets), str(tmp_path / "tables"), "--dry-run"],
                          cwd=root, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "2 scenes of" in done.stderr
    assert "plan: 2 scene(s) x 2 variant(s) x 1 seed(s) = 4 runs" in done.stdout + done.stderr
    first = subprocess.run(["bash", "benchmarks/random_set_tables.sh", str(sets), str(tmp_path / "tables"), "--first", "1",
                            "--dry-run"], cwd=root, capture_output=True, text=True)
    assert first.returncode == 0, first.stderr
    assert "1 scenes of" in first.stderr and "= 2 runs" in first.stdout + first.stderr   # random_3 alone
    only = subprocess.run(["bash", "benchmarks/random_set_tables.sh", str(sets), str(tmp_path / "tables"), "--only",
                           "random_7", "--dry-run"], cwd=root, capture_output=True, text=True)
    assert only.returncode == 0, only.stderr
    assert "1 scenes of" in only.stderr and "= 2 runs" in only.stdout + only.stderr   # random_7 alone
    absent = subprocess.run(["bash", "benchmarks/random_set_tables.sh", str(sets), str(tmp_path / "tables2"), "--only",
                             "random_7,random_9", "--dry-run"], cwd=root, capture_output=True, text=True)
    assert absent.returncode == 2 and "--only: random_9 is not a finished scene" in absent.stderr
    assert not (tmp_path / "tables2").exists()
    empty = subprocess.run(["bash", "benchmarks/random_set_tables.sh", str(tmp_path / "none"), str(tmp_path / "t")],
                           cwd=root, capture_output=True, text=True)
    assert empty.returncode == 2 and "no finished drawn scene" in empty.stderr


def test_a_candidate_the_harness_took_fulls_run_for_reads_fulls(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """floor-by-meeting-trust has no run folder where Full's haze lines gave no meeting point (the
    harness took Full's run, eval/twins.py): the row reads Full's scores for it and names it; where
    its floor differs and it has not finished, the scene has no row."""
    from tests.test_twins import write_full_record

    tables, datasets = tmp_path / "tables", tmp_path / "sets"
    for scene, colour in (("random_1", None), ("random_2", [0.3, 0.3, 0.3])):
        _dataset(datasets, scene, 1.0)
        _run(tables, scene, "full", 21.0, 20.0)
        write_full_record(tables / "runs" / scene / "full" / "seed0-x", colour, lines=250, met=0.5)
    out = tmp_path / "per_scene.csv"
    assert main(["--tables", str(tables), "--datasets", str(datasets), "--out", str(out), "--split", "val",
                 "--candidates", "floor-by-meeting-trust"]) == 0
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert [(r["scene"], r["floor_by_meeting_trust_psnr"], r["same_as_full"]) for r in rows] == [
        ("random_1", "20.0", "floor-by-meeting-trust")]
    assert "- Full +0.00 ± 0.00 dB, ahead on 0 of 1" in capsys.readouterr().out
