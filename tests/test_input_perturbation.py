"""The smoky frames moved by one level (benchmarks/input_perturbation.py): the copy, the harness call
and the comparison."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks.full_seed_runs import tables_command
from benchmarks.input_perturbation import compare, main, noisy_name, perturb_dataset
from contracts.dataset_format import validate_dataset
from contracts.imageio import read_png
from eval.harness_cli import build_parser
from tests.test_smokeseer_data import write_splat_dataset


def test_the_copy_moves_each_smoky_value_by_one_level_and_nothing_else(tmp_path: Path) -> None:
    src = write_splat_dataset(tmp_path / "splat", n_rgb=4, n_thermal=3)
    dst = tmp_path / "out" / noisy_name("splat", 1)
    rec = perturb_dataset(src, dst, 1, noise_seed=3)
    validate_dataset(dst)
    originals = sorted((src / "rgb" / "smoky").glob("*.png"))
    assert rec["frames"] == len(originals) == 4
    clipped = 0
    for path in originals:
        before = read_png(path).astype(int)
        after = read_png(dst / "rgb" / "smoky" / path.name).astype(int)
        step = after - before
        edge = ((before == 0) | (before == 255)) & (step == 0)   # clipped values stay
        assert set(np.unique(step[~edge])) == {-1, 1}
        assert 0.3 < (step == 1).mean() < 0.7
        clipped += int(edge.sum())
    assert rec["clipped_values"] == clipped
    for path in src.rglob("*"):
        if path.is_file() and path.parent.name != "smoky" or path.parent.parent.name == "thermal":
            assert (dst / path.relative_to(src)).read_bytes() == path.read_bytes(), path
    assert json.loads((dst / "perturbation.json").read_text())["noise_seed"] == 3
    # the same noise again keeps the copy; other noise in its place is refused
    assert perturb_dataset(src, dst, 1, noise_seed=3) == rec
    with pytest.raises(ValueError, match="holds another perturbation"):
        perturb_dataset(src, dst, 1, noise_seed=4)
    assert not list((tmp_path / "out").glob(".*partial"))


def test_the_harness_call_trains_full_on_both_and_the_rows_pair_them(tmp_path: Path) -> None:
    pairs = {"room": Path("data/standard/room"), "room-noisy1": Path("o/datasets/room-noisy1")}
    args = build_parser().parse_args(tables_command(pairs, "standard", 0, 2, Path("o/tables"))[3:])
    assert args.methods == ["full"] and args.scenes == ["room", "room-noisy1"] and not args.ablations
    assert args.dataset == ["room=data/standard/room", "room-noisy1=o/datasets/room-noisy1"]
    tables, standard = tmp_path / "tables", tmp_path / "standard"
    runs = ((tables, "room", "c", 14.0), (tables, "room-noisy1", "c", 14.15), (standard, "room", "c", 13.0),
            (standard, "room", "d", 12.0), (tables, "room-noisy1", "d", 12.5), (tables, "room-noisy1", "e", 11.0),
            (tables, "machine", "c", 20.0))  # machine's copy unfinished; room's copy under "e" has no original
    for folder, scene, digest, psnr in runs:
        run = folder / "runs" / scene / "full" / f"seed0-{digest}"
        run.mkdir(parents=True)
        (run / "train_log.csv").write_text("iteration\n")
        (run / "metrics.json").write_text(json.dumps({"validation": {"psnr": psnr + 1}}))
        (run / "harness.json").write_text(json.dumps({"scene": scene, "variant": "full", "seed": 0, "status": "ok",
                                                      "code_digest": digest * 64, "metrics": {"psnr": psnr}}))
    pairs = [(r["scene"], r["trainer"], r["perturbed_minus_original"], r["perturbed_val_psnr"], r["originals_from"])
             for r in compare(tables, [tables], ["room", "machine"], 1, 0)]
    assert pairs == [("room", "c" * 8, 0.15, 15.15, str(tables))]
    # the originals' folder is read first, each pair under one trainer version
    pairs = [(r["scene"], r["trainer"], r["perturbed_minus_original"], r["originals_from"])
             for r in compare(tables, [standard, tables], ["room", "machine"], 1, 0)]
    assert pairs == [("room", "c" * 8, 1.15, str(standard)), ("room", "d" * 8, 0.5, str(standard))]


def test_bad_input_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--out", str(tmp_path), "--datasets", str(tmp_path), "--scenes", "room"]) == 2
    assert "no dataset for room" in capsys.readouterr().err
    write_splat_dataset(tmp_path / "sets" / "room", n_rgb=4, n_thermal=3)
    assert main(["--out", str(tmp_path / "o"), "--datasets", str(tmp_path / "sets"), "--scenes", "room",
                 "--levels", "0"]) == 2
    assert "--levels: 1 to 64" in capsys.readouterr().err
    assert main(["--out", str(tmp_path / "o"), "--datasets", str(tmp_path / "sets"), "--scenes", "room",
                 "--compare-only"]) == 2
    assert "no scene of room has both runs finished under one trainer" in capsys.readouterr().err
