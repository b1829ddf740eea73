"""Table and figure writers on fixture results with known values."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from eval.figures import pick_test_frame, read_psnr_curve, write_psnr_vs_time, write_qualitative_grid
from eval.runs import RunResult
from eval.tables import Stat, format_stat, seed_stat, write_tables


def _run(scene: str, variant: str, seed: int, psnr: float | None, status: str = "ok", **m: float) -> RunResult:
    metrics = {"psnr": psnr, "ssim": m.get("ssim", 0.5), "lpips": m.get("lpips"),
               "lpips_status": "skipped: no weights" if m.get("lpips") is None else "ok: alex",
               "psnr_input": 12.0, "depth_absrel": 0.1, "depth_rmse": 0.3, "mask_iou": None}
    return RunResult(scene, variant, seed, status, f"/nonexistent/{scene}/{variant}/{seed}", "h" * 64,
                     metrics=metrics if status == "ok" else {}, wall_time_s=10.0,
                     error="" if status == "ok" else "RuntimeError: exploded")


FIXTURE = [
    # Full: seed 0 scenes (20, 22) -> 21; seed 1 (21, 23) -> 22 => 21.5 ± 0.7071
    _run("a", "full", 0, 20.0, ssim=0.70), _run("b", "full", 0, 22.0, ssim=0.80),
    _run("a", "full", 1, 21.0, ssim=0.72), _run("b", "full", 1, 23.0, ssim=0.82),
    # RGB only, with LPIPS: one run failed -> seed 1 averages scene a alone
    _run("a", "rgb-only", 0, 15.0, lpips=0.30), _run("b", "rgb-only", 0, 17.0, lpips=0.40),
    _run("a", "rgb-only", 1, 16.0, lpips=0.32), _run("b", "rgb-only", 1, None, status="failed"),
    _run("a", "no-depth", 0, 19.0), _run("b", "no-depth", 0, 19.5),
    _run("a", "no-depth", 1, 19.2), _run("b", "no-depth", 1, 19.7),
]


def test_seed_stat_known_values() -> None:
    s = seed_stat({0: [20.0, 22.0], 1: [21.0, 23.0]})
    assert s.mean == pytest.approx(21.5) and s.std == pytest.approx(math.sqrt(0.5)) and s.n_seeds == 2
    one = seed_stat({3: [1.0, 2.0]})
    assert one.mean == 1.5 and one.std is None
    assert seed_stat({0: []}) == Stat(None, None, 0)
    assert format_stat(s, 2) == "21.50 ± 0.71"
    assert format_stat(one, 3, latex=True) == "1.500"
    assert format_stat(s, 1, latex=True) == r"21.5 $\pm$ 0.7"


def test_table1_and_table2_contents(tmp_path: Path) -> None:
    paths = write_tables(FIXTURE, tmp_path)
    md = paths["table1.md"].read_text()
    assert "| Ours (Full) | 21.50 ± 0.71 | 0.760 ± 0.014 | skipped: no weights | 19.92 | 0.760 | 0.247 |" in md
    # RGB only: seed 0 = 16.0, seed 1 = 16.0 (only scene a) -> 16.00 ± 0.00, flagged
    assert "| Ours (RGB only) | 16.00 ± 0.00 |" in md and "3/4 †" in md
    assert "0.335 ± 0.021" in md  # LPIPS: seed means 0.35, 0.32
    assert "1 failed, 3 of 4 runs averaged" in md
    assert "Ours (RGB only): its seeds are means over different numbers of scenes (seed 0: 2, seed 1: 1)" in md
    assert "Ours (Full): its seeds are means" not in md
    assert "ImgDehaze" not in md  # no runs of it: no made-up row
    rows = {(r["variant"], r["metric"]): r for r in csv.DictReader(open(paths["table1.csv"]))}
    assert float(rows[("full", "psnr")]["mean"]) == pytest.approx(21.5)
    assert float(rows[("full", "psnr")]["std"]) == pytest.approx(math.sqrt(0.5))
    assert rows[("full", "lpips")]["mean"] == "" and rows[("full", "mask_iou")]["mean"] == ""
    assert rows[("rgb-only", "psnr")]["runs_failed"] == "1" and float(rows[("rgb-only", "psnr")]["paper"]) == 15.08
    t2 = paths["table2.md"].read_text()
    assert "| w/o depth | 19.35 ± 0.14 |" in t2 and "| 19.88 |" in t2
    assert t2.index("Ours (Full)") < t2.index("w/o depth")
    tex = paths["table2.tex"].read_text()
    assert r"w/o depth & 19.35 $\pm$ 0.14" in tex and r"\toprule" in tex and "_" not in tex.replace(r"\_", "")
    per_scene = list(csv.DictReader(open(paths["per_scene.csv"])))
    a_full = next(r for r in per_scene if r["scene"] == "a" and r["variant"] == "full" and r["metric"] == "psnr")
    assert float(a_full["mean"]) == pytest.approx(20.5) and float(a_full["std"]) == pytest.approx(math.sqrt(0.5))


def test_estimated_stage1_row_sits_beside_ground_truth_full_in_table1(tmp_path: Path) -> None:
    # Estimated Stage 1: seed 0 scenes (18, 19) -> 18.5; seed 1 (19, 20) -> 19.5 => 19.00 ± 0.71
    estimated = [_run("a", "full-estimated", 0, 18.0), _run("b", "full-estimated", 0, 19.0),
                 _run("a", "full-estimated", 1, 19.0), _run("b", "full-estimated", 1, 20.0)]
    paths = write_tables(FIXTURE + estimated, tmp_path)
    md = paths["table1.md"].read_text()
    assert "| Ours (Full, estimated Stage 1) | 19.00 ± 0.71 | 0.500 ± 0.000 | skipped: no weights | — | — | — |" in md
    lines = md.splitlines()
    full = next(i for i, ln in enumerate(lines) if ln.startswith("| Ours (Full) |"))
    assert lines[full + 1].startswith("| Ours (Full, estimated Stage 1) |")
    assert "Ours (Full): Stage 1 (smoke masks, thermal-to-RGB registration) read from the generator's ground truth; at the standard profile the mask floor acts where the images say the smoke may reach 0.4." in md
    assert "stage1=estimate" in md and "dehazed frames" not in md.split("Ours (Full, estimated")[-1]
    rows = {(r["variant"], r["metric"]): r for r in csv.DictReader(open(paths["table1.csv"]))}
    assert float(rows[("full-estimated", "psnr")]["mean"]) == pytest.approx(19.0)
    assert rows[("full-estimated", "psnr")]["paper"] == ""
    assert "Ours (Full, estimated Stage 1)" in paths["table1.tex"].read_text()
    assert "Ours (Full, estimated" not in paths["table2.md"].read_text()


def test_a_table_of_runs_from_two_devices_says_so(tmp_path: Path) -> None:
    assert "more than one device" not in write_tables(FIXTURE, tmp_path)["table1.md"].read_text()
    mixed = [RunResult(**{**r.to_json(), "device": "cuda"}) if r.seed == 1 and r.variant == "full" else r
             for r in FIXTURE]
    paths = write_tables(mixed, tmp_path)
    assert "more than one device (5 on cpu, 2 on cuda)" in paths["table1.md"].read_text()
    assert "more than one device (6 on cpu, 2 on cuda)" in paths["table2.md"].read_text()


def test_no_table2_without_ablations(tmp_path: Path) -> None:
    paths = write_tables([r for r in FIXTURE if r.variant != "no-depth"], tmp_path)
    assert "table2.md" not in paths and not (tmp_path / "table2.md").exists()


def test_psnr_curve_and_plot(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "train_log.csv").write_text("iteration,stage,wall_s,loss,test_psnr\n0,2,0.0,1.0,\n"
                                           "5,3,2.0,0.5,14.5\n10,3,4.0,0.4,15.5\n")
    r = RunResult("a", "imgdehaze-dcp", 0, "ok", str(run_dir), "h", metrics={"psnr": 16.0},
                  wall_time_s=5.0, prep_time_s=1.0)
    pts = read_psnr_curve(r)
    assert pts == [(5, 3.0, 14.5, "train_log"), (10, 5.0, 15.5, "train_log"), (10, 6.0, 16.0, "final")]
    csv_path, png_path = write_psnr_vs_time([r, _run("a", "full", 1, None, status="failed")], tmp_path)
    rows = list(csv.DictReader(open(csv_path)))
    assert [float(x["wall_s"]) for x in rows] == [3.0, 5.0, 6.0]
    assert png_path.stat().st_size > 1000


def test_qualitative_grid_uses_the_test_frame(tmp_path: Path) -> None:
    ds = tmp_path / "ds"
    for sub in ("rgb/smoky", "rgb/clean", "thermal/smoky"):
        (ds / sub).mkdir(parents=True)
    frames = [{"file_stem": f"{i:04d}", "time": i / 4, "split": "test" if i in (1, 3) else "train"} for i in range(5)]
    (ds / "transforms_rgb.json").write_text(json.dumps({"frames": frames}))
    (ds / "transforms_thermal.json").write_text(json.dumps({"frames": [{"file_stem": "0000", "time": 0.7}]}))
    for i in range(5):
        for sub in ("rgb/smoky", "rgb/clean"):
            Image.fromarray(np.full((8, 8, 3), 40 * i, np.uint8)).save(ds / sub / f"{i:04d}.png")
    Image.fromarray(np.arange(64, dtype=np.uint16).reshape(8, 8) * 100).save(ds / "thermal/smoky/0000.png")
    run = tmp_path / "run"
    (run / "renders/surface").mkdir(parents=True)
    Image.fromarray(np.full((8, 8, 3), 255, np.uint8)).save(run / "renders/surface/0003.png")
    results = [RunResult("s", "full", 0, "ok", str(run), "h", metrics={"psnr": 1.0}),
               _run("s", "rgb-only", 0, None, status="failed")]
    out = write_qualitative_grid(results, {"s": ds}, ["thermal", "rgb", "gt", "full", "rgb-only"],
                                 tmp_path / "fig.png", "grid")
    assert pick_test_frame(ds)["file_stem"] == "0003"  # middle of the test views (0001, 0003)
    img = np.asarray(Image.open(out))
    assert img.shape[0] > 100 and img.shape[1] > 500


def _log(folder: Path, stage2: list[tuple[int, int, float]]) -> str:
    """A train_log.csv with these Stage-2 rows (iteration, Gaussians, loss) and one Stage-3 row;
    the wall times differ per folder, as they do between two machines."""
    folder.mkdir(parents=True)
    wall = float(len(str(folder)))
    lines = ["stage,iteration,wall_s,n_gaussians,n_smoke,loss"]
    lines += [f"2,{it},{wall + it},{n},,{loss}" for it, n, loss in stage2]
    lines.append(f"3,10,{wall + 99},{stage2[-1][1]},7,0.5")
    (folder / "train_log.csv").write_text("\n".join(lines) + "\n")
    return str(folder)


def test_table2_says_where_an_ablation_trained_a_stage2_apart_from_fulls(tmp_path: Path) -> None:
    """Scene a, seed 1: the ablation's Stage 2 parts from Full's in the loss's last digit (rounding);
    every other pair agrees row for row, wall times aside. A twin of Full is not counted."""
    same = [(10, 500, 0.25), (20, 520, 0.125)]
    rounded = [(10, 500, 0.25), (20, 520, 0.125001)]
    runs = []
    for scene in ("a", "b"):
        for seed in (0, 1):
            full = _run(scene, "full", seed, 22.0)
            full = RunResult(**{**full.to_json(), "run_dir": _log(tmp_path / scene / "full" / str(seed), same)})
            abl = _run(scene, "no-mask", seed, 21.0)
            log = rounded if (scene, seed) == ("a", 1) else same
            abl = RunResult(**{**abl.to_json(), "run_dir": _log(tmp_path / scene / "no-mask" / str(seed), log)})
            runs += [full, abl]
    twin = RunResult(**{**_run("a", "no-mono", 1, 22.0).to_json(), "run_dir": runs[2].run_dir,
                        "same_as": "full", "same_as_reason": "Full held the colour"})
    md = write_tables(runs + [twin], tmp_path / "tables")["table2.md"].read_text()
    assert ("w/o mask: its Stage 2 ended apart from Full's on 1 of the 4 runs compared "
            "(seed 0: 0 of 2, seed 1: 1 of 2).") in md
    assert "w/o mono: its Stage 2" not in md
    agreeing = [r if r.run_dir != runs[3].run_dir else
                RunResult(**{**r.to_json(), "run_dir": _log(tmp_path / "a" / "no-mask" / "again", same)})
                for r in runs]
    assert "ended apart" not in write_tables(agreeing, tmp_path / "again")["table2.md"].read_text()


def test_table2_ablations_share_fulls_stage2_settings() -> None:
    """What the Stage-2 footnote above rests on: every ablation trains Full's Stage 2."""
    from eval.runs import ABLATIONS
    from smokeseer.config import make_config

    for profile in ("quick", "standard"):
        for seed in (0, 2):
            full = make_config("full", profile, seed).stage2_sha256()
            assert all(make_config(v.mode, profile, seed, dict(v.overrides)).stage2_sha256() == full
                       for v in ABLATIONS.values())


def test_a_partly_scored_lpips_column_shows_no_mean_over_a_subset(tmp_path: Path) -> None:
    """Runs trained before the LPIPS weights were installed beside runs trained after: a mean over the
    scored runs alone would be over other scenes than the PSNR beside it, so the cell says how many
    runs were scored instead, in the tables and in per_scene.csv."""
    mixed = [_run("a", "full", 0, 20.0, lpips=0.30), _run("b", "full", 0, 22.0),
             _run("a", "full", 1, 21.0, lpips=0.32), _run("b", "full", 1, 23.0)]
    paths = write_tables(mixed, tmp_path)
    md = paths["table1.md"].read_text()
    assert "| Ours (Full) | 21.50 ± 0.71 | 0.500 ± 0.000 | partial: 2/4 runs |" in md
    assert "Ours (Full): LPIPS was scored in 2 of its 4 runs" in md
    rows = {(r["variant"], r["metric"]): r for r in csv.DictReader(open(paths["table1.csv"]))}
    assert rows[("full", "lpips")]["mean"] == ""
    per_scene = {(r["scene"], r["metric"]): r for r in csv.DictReader(open(paths["per_scene.csv"]))}
    assert float(per_scene[("a", "lpips")]["mean"]) == pytest.approx(0.31)  # scene a: scored at both seeds
    assert per_scene[("b", "lpips")]["mean"] == ""


def test_lpips_scored_after_training_is_said_so_beneath_the_table(tmp_path: Path) -> None:
    """Runs whose LPIPS benchmarks/rescore_lpips.py wrote from their saved renders get the mean as
    any other, and a note naming where it came from; a table of trainer-scored runs has none."""
    how = "rescored from the run's 8-bit surface renders by benchmarks/rescore_lpips.py, alex, x weights"
    runs = [_run("a", "full", 0, 20.0, lpips=0.30), _run("b", "full", 0, 22.0, lpips=0.40),
            _run("a", "rgb-only", 0, 15.0, lpips=0.50), _run("b", "rgb-only", 0, 17.0, lpips=0.60)]
    for r in runs[:3]:
        r.metrics["lpips_status"] = how
    md = write_tables(runs, tmp_path)["table1.md"].read_text()
    assert "| Ours (Full) | 21.00 | 0.500 | 0.350 |" in md and "| Ours (RGB only) | 16.00 | 0.500 | 0.550 |" in md
    assert f"- LPIPS: {how}, in 3 of the 4 runs; scored after training" in md
    runs[3].metrics["lpips_status"] = how
    md = write_tables(runs, tmp_path)["table1.md"].read_text()
    assert f"- LPIPS: {how}; scored after training" in md
    md = write_tables(FIXTURE, tmp_path / "trainer")["table1.md"].read_text()
    assert "scored after training" not in md
