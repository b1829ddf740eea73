"""The clean-ceiling dataset of eval/clean_ceiling.py, read back by the trainer's own loader; the
ceiling runs reused, retrained or (--finished-only) read without training."""
from __future__ import annotations

import csv
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks import clean_ceiling
from contracts.results_format import PROVENANCE_KEYS, ResultsFormatError
from eval.clean_ceiling import (ceiling_digests, ceiling_run, derive_clean_dataset, finished_ceiling,
                                headroom_recovered, smoky_input_psnr, table_test_metrics)
from eval.finished_runs import pick_digest
from eval.runs import CANDIDATES
from eval.tables import RESCORED_LPIPS
from scenes.load import load_scene
from smokeseer.cli import build_parser, overrides_from_args
from tests.results_builder import write_metrics

ROOT = Path(__file__).resolve().parents[1]


def test_derived_dataset_trains_on_the_clean_frames(demo_dataset: Path, tmp_path: Path) -> None:
    original = load_scene(demo_dataset, all_ground_truth=True)
    derived = load_scene(derive_clean_dataset(demo_dataset, tmp_path / "ceiling"), all_ground_truth=True)
    assert original.rgb.masks is not None and (original.rgb.masks > 0).any()
    assert not np.array_equal(original.rgb.images, original.rgb.clean)  # the demo has smoke to remove
    np.testing.assert_array_equal(derived.rgb.images, original.rgb.clean)
    np.testing.assert_array_equal(derived.rgb.clean, original.rgb.clean)
    assert derived.rgb.masks is None and not derived.smoke_present
    # A world without smoke has no smoke shadow: the shadowed frames are dropped with the smoke opacity.
    assert original.rgb.shadowed is not None and derived.rgb.shadowed is None
    assert not (tmp_path / "ceiling" / "rgb" / "shadowed").exists()
    # Thermal is read through the scene's own thermal scale, so compare the files it reads.
    for smoky, clean in (("smoky", "clean"), ("smoky_radiance", "clean_radiance")):
        assert (tmp_path / "ceiling" / "thermal" / smoky).resolve() == (demo_dataset / "thermal" / clean).resolve()
    assert not np.array_equal(derived.thermal.images, original.thermal.images)  # smoke is seen in thermal too
    assert derived.thermal.masks is None and not (tmp_path / "ceiling" / "thermal" / "smoke_alpha").exists()
    note = json.loads((tmp_path / "ceiling" / "dataset.json").read_text())["derived_from"]
    assert note["dataset"] == str(demo_dataset.resolve())
    assert "rgb/smoky links to rgb/clean" in note["change"] and "thermal/smoky links to thermal/clean" in note["change"]
    assert not list(tmp_path.glob(".*staging"))


def test_a_dataset_without_clean_frames_is_refused(demo_dataset: Path, tmp_path: Path) -> None:
    copy = tmp_path / "no_clean"
    shutil.copytree(demo_dataset, copy)
    meta = json.loads((copy / "dataset.json").read_text())
    meta["passes"]["rgb"].remove("clean")
    (copy / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"dataset\.json: field 'passes\.rgb' has no 'clean'"):
        derive_clean_dataset(copy, tmp_path / "ceiling")
    assert not (tmp_path / "ceiling").exists()


def test_smoky_input_psnr_reads_a_finished_run_of_the_profile(tmp_path: Path) -> None:
    def run(method: str, profile: str, status: str, psnr_input: float) -> None:
        write_metrics(tmp_path / "house" / method / "seed0-abc", scene="house", method=method, profile=profile,
                      seed=0, status=status, metrics={"psnr_input": psnr_input},
                      **({"validation": {"psnr_input": psnr_input - 1}} if status == "ok" else {}))

    assert smoky_input_psnr("house", "standard", tmp_path) == (None, None)
    run("full", "quick", "ok", 20.0)
    run("no-mask", "standard", "failed", 25.0)
    assert smoky_input_psnr("house", "standard", tmp_path) == (None, None)
    run("rgb-only", "standard", "ok", 31.0)
    assert smoky_input_psnr("house", "standard", tmp_path) == (31.0, 30.0)
    assert smoky_input_psnr("house", "standard", tmp_path, "cafe0123") == (None, None)  # no run of that trainer
    (tmp_path / "house" / "full" / "seed0-abc" / "metrics.json").write_text(json.dumps({"profile": "standard"}))
    with pytest.raises(ResultsFormatError, match=r"full/seed0-abc/metrics\.json: missing field 'format'"):
        smoky_input_psnr("house", "standard", tmp_path)


def test_table_scores_are_the_runs_own_digest_and_the_headroom_its_share_of_the_gap(tmp_path: Path) -> None:
    for digest, psnr, lpips in (("aaaa1111", 21.0, 0.3), ("bbbb2222", 23.0, 0.2)):
        write_metrics(tmp_path / "house" / "full" / f"seed0-{digest}", scene="house", method="full",
                      profile="standard", seed=0, metrics={"psnr": psnr, "lpips": lpips},
                      provenance={**dict.fromkeys(PROVENANCE_KEYS), "source_digest": digest * 8})
    scores = table_test_metrics("house", "full", 0, "standard", "bbbb2222", tmp_path)
    assert scores is not None and (scores["psnr"], scores["lpips"]) == (23.0, 0.2)
    assert table_test_metrics("house", "full", 1, "standard", "bbbb2222", tmp_path) is None
    assert table_test_metrics("house", "rgb-only", 0, "standard", "bbbb2222", tmp_path) is None
    assert headroom_recovered(23.0, 20.0, 32.0) == pytest.approx(0.25)
    assert headroom_recovered(19.0, 20.0, 32.0) == pytest.approx(-1 / 12)  # under the input: negative
    assert headroom_recovered(23.0, 32.0, 31.0) is None and headroom_recovered(None, 20.0, 32.0) is None


def _finished_by(digest: str, seed: int = 0, profile: str = "standard"):
    """A stand-in for the trainer's command: it writes the folder's metrics.json, as a run of
    trainer ``digest`` at this seed and profile does, and records which folders it was asked to train."""
    calls: list[Path] = []

    def train(folder: Path) -> None:
        calls.append(folder)
        write_metrics(folder, scene="house", method="full", profile=profile, seed=seed, metrics={"psnr": 30.0},
                      provenance={**dict.fromkeys(PROVENANCE_KEYS), "source_digest": digest * 8})
    train.calls = calls  # type: ignore[attr-defined]
    return train


def test_a_ceiling_of_other_trainer_code_is_retrained_and_replaced_only_when_finished(tmp_path: Path) -> None:
    run_dir = tmp_path / "house" / "full"
    old, new = "aaaa1111", "bbbb2222"
    _finished_by(old)(run_dir)
    (run_dir / "renders").mkdir()
    fresh = tmp_path / "house" / f"full-{new}-standard-seed0"

    def interrupted(folder: Path) -> None:
        (folder / "checkpoints").mkdir(parents=True)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        ceiling_run(run_dir, new * 8, "standard", 0, interrupted)
    assert json.loads((run_dir / "metrics.json").read_text())["provenance"]["source_digest"] == old * 8
    assert (fresh / "checkpoints").is_dir()  # left to resume from

    train = _finished_by(new)
    doc = ceiling_run(run_dir, new * 8, "standard", 0, train)
    assert train.calls == [fresh]
    assert doc["provenance"]["source_digest"] == new * 8
    assert json.loads((run_dir / "metrics.json").read_text()) == doc
    assert not (run_dir / "renders").exists()  # nothing of the old run is left in the folder
    assert sorted(p.name for p in (tmp_path / "house").iterdir()) == ["full"]

    again = _finished_by(new)
    assert ceiling_run(run_dir, new * 8, "standard", 0, again) == doc and again.calls == []  # reused


@pytest.mark.parametrize("seed, profile", [(1, "standard"), (0, "quick")])
def test_a_ceiling_of_another_seed_or_profile_is_retrained_not_reused(tmp_path: Path, seed: int, profile: str) -> None:
    run_dir = tmp_path / "house" / "full"
    _finished_by("bbbb2222")(run_dir)
    train = _finished_by("bbbb2222", seed, profile)
    doc = ceiling_run(run_dir, "bbbb2222" * 8, profile, seed, train)
    assert train.calls == [tmp_path / "house" / f"full-bbbb2222-{profile}-seed{seed}"]
    assert (doc["seed"], doc["profile"]) == (seed, profile)


def test_a_trained_run_unlike_the_request_is_refused_not_swapped_in(tmp_path: Path) -> None:
    run_dir = tmp_path / "house" / "full"
    _finished_by("aaaa1111")(run_dir)
    with pytest.raises(RuntimeError, match=r"full-bbbb2222-standard-seed1/metrics\.json: .*seed 0, not 1"):
        ceiling_run(run_dir, "bbbb2222" * 8, "standard", 1, _finished_by("bbbb2222", seed=0))
    assert json.loads((run_dir / "metrics.json").read_text())["provenance"]["source_digest"] == "aaaa1111" * 8


def test_a_swap_cut_between_its_renames_is_completed_without_training(tmp_path: Path) -> None:
    run_dir = tmp_path / "house" / "full"
    _finished_by("bbbb2222")(tmp_path / "house" / "full-bbbb2222-standard-seed0")
    train = _finished_by("bbbb2222")
    assert ceiling_run(run_dir, "bbbb2222" * 8, "standard", 0, train)["provenance"]["source_digest"] == "bbbb2222" * 8
    assert train.calls == [] and sorted(p.name for p in (tmp_path / "house").iterdir()) == ["full"]


def test_a_candidates_ceiling_is_checked_against_its_settings(tmp_path: Path) -> None:
    """A candidate's ceiling run (Full with overrides) is reused only where its config.json holds
    every override; a run of other settings, or one without config.json, is retrained beside it."""
    run_dir = tmp_path / "plant" / "thermal-box-filtered"
    settings = {"stage3.thermal_supersample": 2}

    def finished(folder: Path, supersample: int | None) -> None:
        _finished_by("bbbb2222")(folder)
        if supersample is not None:
            (folder / "config.json").write_text(json.dumps({"mode": "full", "stage3": {"thermal_supersample": supersample}}))

    finished(run_dir, 2)
    assert finished_ceiling(run_dir, "bbbb2222" * 8, "standard", 0, settings) is not None
    assert finished_ceiling(run_dir, "bbbb2222" * 8, "standard", 0, {"stage3.thermal_supersample": 3}) is None
    assert finished_ceiling(run_dir, "bbbb2222" * 8, "standard", 0, {"stage3.carve_by": "depth"}) is None
    finished(run_dir, 3)  # the candidate's setting has changed since this run
    calls: list[Path] = []

    def train(folder: Path) -> None:
        calls.append(folder)
        finished(folder, 2)

    doc = ceiling_run(run_dir, "bbbb2222" * 8, "standard", 0, train, settings)
    assert calls == [tmp_path / "plant" / "thermal-box-filtered-bbbb2222-standard-seed0"] and doc["status"] == "ok"
    assert json.loads((run_dir / "config.json").read_text())["stage3"]["thermal_supersample"] == 2
    with pytest.raises(RuntimeError, match=r"no config\.json to check its settings against"):
        ceiling_run(tmp_path / "room" / "thermal-box-filtered", "bbbb2222" * 8, "standard", 0,
                    lambda folder: finished(folder, None), settings)


def test_finished_ceiling_reads_a_named_trainers_run_and_moves_nothing(tmp_path: Path) -> None:
    run_dir = tmp_path / "house" / "full"
    _finished_by("aaaa1111")(run_dir)
    assert finished_ceiling(run_dir, "aaaa1111" * 8, "standard", 0)["provenance"]["source_digest"] == "aaaa1111" * 8
    assert finished_ceiling(run_dir, "bbbb2222" * 8, "standard", 0) is None  # not trained: nothing else happens
    assert finished_ceiling(run_dir, "aaaa1111" * 8, "standard", 1) is None
    assert finished_ceiling(run_dir, "aaaa1111" * 8, "quick", 0) is None
    # A retrain that finished beside the old run but was not swapped in yet is read where it is.
    _finished_by("bbbb2222")(tmp_path / "house" / "full-bbbb2222-standard-seed0")
    assert finished_ceiling(run_dir, "bbbb2222" * 8, "standard", 0)["provenance"]["source_digest"] == "bbbb2222" * 8
    assert sorted(p.name for p in (tmp_path / "house").iterdir()) == ["full", "full-bbbb2222-standard-seed0"]
    # The prefix is resolved as regenerate-tables --digest resolves it, over every finished ceiling run.
    digests = ceiling_digests(tmp_path)
    assert sorted(digests) == ["aaaa1111" * 8, "bbbb2222" * 8]
    assert pick_digest(digests, "bbbb", str(tmp_path)) == "bbbb2222" * 8
    with pytest.raises(ValueError, match=r"--digest cafe: no run in .* starting so \(found aaaa1111, bbbb2222\)"):
        pick_digest(digests, "cafe", str(tmp_path))


def _main(monkeypatch: pytest.MonkeyPatch, *args: str) -> None:
    monkeypatch.setattr(sys, "argv", ["clean_ceiling.py", *args])
    clean_ceiling.main()


def test_finished_only_tables_the_committed_ceilings_without_training(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """house's committed ceilings (trainer d65d2bcb) give the committed rows, LPIPS included, and
    no derived dataset is made."""
    ceilings, house = ROOT / "data" / "clean_ceiling_standard", ROOT / "data" / "standard" / "house"
    out = tmp_path / "ceiling.csv"
    common = ["--out", str(ceilings), str(house), "--tables", str(ROOT / "data" / "tables_standard" / "runs")]
    _main(monkeypatch, *common, "--finished-only", "--digest", "d65d2bcb", "--csv", str(out))
    rows = list(csv.DictReader(out.open()))
    committed = [r for r in csv.DictReader((ROOT / "benchmarks" / "results" / "standard" / "clean_ceiling.csv").open())
                 if r["scene"] == "house"]
    assert [r["mode"] for r in rows] == ["full", "rgb-only"] and rows == committed
    for row in rows:
        doc = json.loads((ceilings / "house" / row["mode"] / "metrics.json").read_text())
        assert float(row["ceiling_test_lpips"]) == round(doc["metrics"]["lpips"], 4) > 0
        assert row["lpips_status"].startswith(RESCORED_LPIPS)
    assert not (ceilings / "house" / "dataset").exists()
    with pytest.raises(SystemExit, match=r"--digest 00000000: no run in .*clean_ceiling_standard has a code_digest"):
        _main(monkeypatch, *common, "--finished-only", "--digest", "00000000", "--csv", str(tmp_path / "x.csv"))
    with pytest.raises(SystemExit, match="--digest: only with --finished-only"):
        _main(monkeypatch, *common, "--digest", "d65d2bcb", "--csv", str(tmp_path / "x.csv"))
    # A folder with no ceiling of today's trainer: nothing trained, derived or written.
    with pytest.raises(SystemExit, match="no finished ceiling run of trainer .* to table; nothing written"):
        _main(monkeypatch, "--out", str(tmp_path / "none"), str(house), "--finished-only",
              "--csv", str(tmp_path / "x.csv"))
    assert not (tmp_path / "x.csv").exists() and not (tmp_path / "none").exists()
