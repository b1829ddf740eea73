"""The share of the smoke's change a de-smoked surface keeps (eval/smoke_kept.py) and the fire
check's figures and CSV (benchmarks/fire_views.py), against surfaces whose answer is known: the
smoky frames themselves (all kept), the clean frames (none), and halfway between."""
from __future__ import annotations

import csv
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks import fire_views
from contracts.imageio import image01, read_png
from eval.smoke_kept import CHANGE_EDGE, change_kept

ROOT = Path(__file__).resolve().parents[1]
HOUSE = ROOT / "data" / "standard" / "house"  # fire on a crate, committed with the benchmark
CHAIR = ROOT / "data" / "standard" / "chair"  # no fire


def test_the_share_kept_is_the_surfaces_error_along_the_smokes_change() -> None:
    rng = np.random.default_rng(0)
    clean = rng.uniform(0.2, 0.6, (8, 8, 3))
    smoky = clean.copy()
    smoky[:4, :4] += np.array([0.35, -0.05, -0.1])  # a red glow: hue more than brightness
    smoky[6, 6] += 0.5 * CHANGE_EDGE  # a faint change: not counted
    for share in (0.0, 0.5, 1.0):
        kept, change, n = change_kept(smoky, clean, clean + share * (smoky - clean))
        assert n == 16 and kept / change == pytest.approx(share)
    kept, change, _ = change_kept(smoky, clean, clean - 0.5 * (smoky - clean))  # the opposite way: negative
    assert kept / change == pytest.approx(-0.5)
    assert change_kept(clean, clean, smoky)[2] == 0  # no smoke: nothing to keep


def _table_run(tables: Path, variant: str, stems: list[str], frames: str, dataset: Path) -> None:
    """A finished table run of house whose surface renders are the dataset's ``frames`` pass."""
    run = tables / "runs" / "house" / variant / "seed0-test"
    (run / "renders" / "surface").mkdir(parents=True)
    for stem in stems:
        shutil.copy(dataset / "rgb" / frames / f"{stem}.png", run / "renders" / "surface" / f"{stem}.png")
    (run / "train_log.csv").write_text("stage,iteration\n")
    (run / "metrics.json").write_text(json.dumps({"metrics": {"psnr": 30.0, "psnr_input": 31.9}}))
    (run / "harness.json").write_text(json.dumps({"scene": "house", "variant": variant, "seed": 0, "status": "ok",
                                                  "code_digest": "ab" * 32}))


def test_the_fire_check_shows_every_test_view_and_scores_known_surfaces(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """On house's real frames: a surface that is the smoky input keeps all of the smoke's change,
    one that is the clean truth none; chair has no fire and is left out; one figure row per test
    view under a header."""
    committed = sorted((ROOT / "data" / "tables_standard" / "runs" / "house" / "full").glob("seed0-*/renders/surface"))
    stems = sorted(p.stem for p in committed[0].glob("*.png"))
    tables = tmp_path / "tables"
    _table_run(tables, "full", stems, "smoky", HOUSE)
    _table_run(tables, "rgb-only", stems, "clean", HOUSE)
    out = tmp_path / "fire"
    monkeypatch.setattr(sys, "argv", ["fire_views.py", "--tables", str(tables), "--out", str(out), str(HOUSE), str(CHAIR)])
    fire_views.main()
    rows = {r["variant"]: r for r in csv.DictReader((out / "smoke_kept.csv").open())}
    assert float(rows["full"]["smoke_kept"]) == pytest.approx(1.0) and float(rows["rgb-only"]["smoke_kept"]) == 0.0
    assert int(rows["full"]["views"]) == len(stems) >= 3 and 0.0 < float(rows["full"]["strong_share"]) < 1.0
    assert {r["scene"] for r in rows.values()} == {"house"} and sorted(p.name for p in out.iterdir()) == [
        "house.png", "smoke_kept.csv"]
    figure = image01(read_png(out / "house.png"))
    frame = image01(read_png(HOUSE / "rgb" / "clean" / f"{stems[0]}.png"))
    h, w = frame.shape[:2]
    assert figure.shape[:2] == (14 + len(stems) * (h + 2), 4 * w + 6)
    np.testing.assert_allclose(figure[16:16 + h, w + 2:2 * w + 2], frame[..., :3], atol=1 / 255)  # clean column
    # A scene with no run of the version asked for, and no scene left: one line, nothing written.
    monkeypatch.setattr(sys, "argv", ["fire_views.py", "--tables", str(tables), "--out", str(tmp_path / "none"), str(CHAIR)])
    with pytest.raises(SystemExit, match="no scene with a finished run to show; nothing written"):
        fire_views.main()
    assert not (tmp_path / "none").exists()
