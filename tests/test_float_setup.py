"""The float setup a run records, the environment that holds torch to AVX2 on an AVX-512 machine,
and the comparison of the same runs under both (benchmarks/float_setup.py)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from benchmarks.float_setup import DEFAULT_CSV, compare, main, setup_environment, tables_command
from contracts.float_setup import HELD_TO, cpu_facts, float_setup, kernel_vector_flags, machine_of
from eval.harness_cli import build_parser
from tests.results_builder import write_metrics

ROOT = Path(__file__).resolve().parents[1]
PROBE = ("import torch; from contracts.float_setup import float_setup; "
         "print(torch.backends.cpu.get_cpu_capability()); print(float_setup())")


def _probe(setup: str) -> tuple[str, str]:
    done = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, env=setup_environment(setup),
                          capture_output=True, text=True, check=True)
    capability, line = done.stdout.strip().splitlines()
    return capability, line


def test_the_avx2_setup_holds_torch_to_avx2_and_the_run_record_says_so() -> None:
    capability, line = _probe("avx2")
    assert capability == "AVX2"
    assert "torch " in line and " AVX2; held ATEN_CPU_CAPABILITY=avx2 MKL_ENABLE_INSTRUCTIONS=AVX2 " \
        "ONEDNN_MAX_CPU_ISA=AVX2;" in line
    default_capability, default_line = _probe("default")
    assert "; held none;" in default_line
    if "avx512f" in cpu_facts()[1]:
        assert default_capability == "AVX512" and " AVX512; " in default_line


def test_a_float_setup_line_gives_back_its_cpu_and_torch_capability() -> None:
    """machine_of reads what float_setup writes (the tables name each run's machine by it)."""
    import torch

    assert machine_of(float_setup()) == f"{cpu_facts()[0]} {torch.backends.cpu.get_cpu_capability()}"
    assert machine_of("") == machine_of("an older record's line") == "not recorded"


def test_the_setup_environment_replaces_inherited_isa_variables() -> None:
    env = setup_environment("default", {"PATH": "/bin", "ATEN_CPU_CAPABILITY": "default", "MKL_ENABLE_INSTRUCTIONS": "SSE4_2"})
    assert env == {"PATH": "/bin"}
    assert setup_environment("avx2", {"PATH": "/bin"}) == {"PATH": "/bin", **HELD_TO["avx2"]}


def test_the_kernel_builds_the_same_on_avx2_and_avx512_machines() -> None:
    avx2 = ["avx", "avx2", "fma", "sse4_2"]
    assert kernel_vector_flags(avx2) == kernel_vector_flags(avx2 + ["avx512f", "avx512bw"]) == ["-mavx2", "-mfma"]
    assert kernel_vector_flags(["avx", "avx2"]) == []  # no FMA: no vector flags at all


def test_each_side_is_one_valid_regenerate_tables_call() -> None:
    cmd = tables_command(["house", "room"], Path("data/standard"), "standard", 0, 2, Path("out/avx2"))
    args = build_parser().parse_args(cmd[3:])
    assert args.methods == ["full"] and args.seeds == "0," and not args.ablations and args.scenes == ["house", "room"]
    assert args.dataset == ["house=data/standard/house", "room=data/standard/room"]


def _run(tables: Path, scene: str, psnr: float, setup: str, digest: str = "d" * 64, variant: str = "full",
         stages: dict[str, Any] | None = None) -> None:
    run = tables / "runs" / scene / variant / "seed0-abc"
    run.mkdir(parents=True)
    (run / "train_log.csv").write_text("iteration\n")
    write_metrics(run, scene=scene, method=variant, profile="standard", seed=0, validation={"psnr": psnr - 1.0},
                  stages=stages or {})
    (run / "harness.json").write_text(json.dumps(
        {"scene": scene, "variant": variant, "seed": 0, "status": "ok", "metrics": {"psnr": psnr},
         "code_digest": digest, "float_setup": f"cpu X (avx2); torch 2.13.0+cpu {setup}; held none; kernel -mavx2"}))


def test_the_comparison_pairs_scenes_and_refuses_what_cannot_be_compared(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    default, avx2 = tmp_path / "default", tmp_path / "avx2"
    _run(default, "house", 30.0, "AVX512")
    _run(default, "room", 14.0, "AVX512")
    _run(avx2, "house", 29.75, "AVX2")
    rows = compare(default, avx2, 0, ["house", "room"])
    assert [(r["scene"], r["default_psnr"], r["avx2_psnr"], r["avx2_minus_default"], r["avx2_val_psnr"])
            for r in rows] == [("house", 30.0, 29.75, -0.25, 28.75)]
    datasets = tmp_path / "datasets"
    for s in ("house", "room"):
        (datasets / s).mkdir(parents=True)
        (datasets / s / "dataset.json").write_text("{}")
    out_csv = tmp_path / "per_scene.csv"
    assert main(["--out", str(tmp_path), "--scenes", "house,room", "--datasets", str(datasets), "--compare-only",
                 "--csv", str(out_csv)]) == 0
    assert out_csv.read_text().splitlines()[0].startswith("scene,default_psnr,avx2_psnr,avx2_minus_default")
    _run(avx2, "room", 14.0, "AVX512")  # the same kernels on both sides: nothing was compared
    with pytest.raises(ValueError, match="room: both sides trained with torch's AVX512 kernels"):
        compare(default, avx2, 0, ["house", "room"])
    other = tmp_path / "other"
    _run(other, "house", 30.0, "AVX2", digest="e" * 64)
    assert main(["--out", str(tmp_path), "--scenes", "house", "--datasets", str(datasets), "--compare-only",
                 "--default-from", str(other), "--csv", str(out_csv)]) == 2
    assert "holds trainer eeeeeeee" in capsys.readouterr().err


def test_each_scene_pairs_its_runs_under_the_trainer_both_sides_share(tmp_path: Path) -> None:
    """Scenes trained under different trainer versions are compared each under its own; a scene
    whose two sides share no version is refused by name."""
    default, avx2 = tmp_path / "default", tmp_path / "avx2"
    _run(default, "house", 30.0, "AVX512")
    _run(avx2, "house", 29.5, "AVX2")
    _run(default, "room", 14.0, "AVX512", digest="e" * 64)
    _run(avx2, "room", 15.0, "AVX2", digest="e" * 64)
    rows = compare(default, avx2, 0, ["house", "room"])
    assert [(r["scene"], r["trainer"], r["avx2_minus_default"]) for r in rows] == [("house", "dddddddd", -0.5),
                                                                                  ("room", "eeeeeeee", 1.0)]
    _run(default, "plant", 20.0, "AVX512", digest="f" * 64)
    _run(avx2, "plant", 20.0, "AVX2")
    with pytest.raises(ValueError, match="plant: .* holds trainer ffffffff and .* trainer dddddddd"):
        compare(default, avx2, 0, ["house", "room", "plant"])


def test_a_candidate_is_compared_on_its_own_runs_or_on_full_runs_that_stand_for_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--method reads the candidate's runs; on a side where the harness took Full's run for it
    (carve-where-smoky where Full started from one surface) Full's run is its run, and the row says
    on which side. Full's own comparison never reads the candidate's runs."""
    default, avx2 = tmp_path / "default", tmp_path / "avx2"
    _run(default, "room", 11.0, "AVX512", stages={"surface_union": None})  # one surface: carving is moot
    _run(avx2, "room", 12.0, "AVX2", stages={"surface_union": {"kept": 10}})
    _run(avx2, "room", 12.5, "AVX2", variant="carve-where-smoky")
    _run(default, "house", 30.0, "AVX512", stages={"surface_union": {"kept": 10}})  # no carve run: no row
    _run(avx2, "house", 30.0, "AVX2", stages={"surface_union": None})
    rows = compare(default, avx2, 0, ["room", "house"], "carve-where-smoky")
    assert [(r["scene"], r["method"], r["default_psnr"], r["avx2_psnr"], r["full_run_on"]) for r in rows] == \
        [("room", "carve-where-smoky", 11.0, 12.5, "default")]
    assert [(r["scene"], r["avx2_psnr"], r["full_run_on"]) for r in compare(default, avx2, 0, ["room", "house"])] == \
        [("room", 12.0, ""), ("house", 30.0, "")]
    datasets = tmp_path / "datasets"
    (datasets / "room").mkdir(parents=True)
    (datasets / "room" / "dataset.json").write_text("{}")
    monkeypatch.chdir(tmp_path)  # a CSV the user names is the one written, even Full's own default path
    assert main(["--out", str(tmp_path), "--scenes", "room", "--datasets", str(datasets), "--compare-only",
                 "--method", "carve-where-smoky", "--csv", str(DEFAULT_CSV)]) == 0
    assert (tmp_path / DEFAULT_CSV).read_text().splitlines()[1].startswith("room,11.0,12.5,")
    assert not (tmp_path / DEFAULT_CSV.with_name("per_scene-carve-where-smoky.csv")).exists()
    cmd = tables_command(["room"], Path("data/standard"), "standard", 0, 2, Path("out/avx2"), "carve-where-smoky")
    assert build_parser().parse_args(cmd[3:]).candidates == ["carve-where-smoky"]
