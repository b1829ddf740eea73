"""Paths in committed records: relative to the project root inside it (no machine's folders), as
given outside it, and read back to the same place from any working folder."""
from __future__ import annotations

from pathlib import Path

import pytest

from contracts.recorded_paths import recorded_location, recorded_path
from contracts.source import PROJECT_ROOT
from eval.runs import RunResult


def test_a_path_inside_the_project_is_recorded_relative_and_read_back(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    inside = PROJECT_ROOT / "data" / "standard" / "room"
    assert recorded_path(inside) == "data/standard/room"
    monkeypatch.chdir(tmp_path)   # the reader's working folder does not matter
    assert recorded_location(recorded_path(inside)) == inside
    assert recorded_path(tmp_path / "capture") == str((tmp_path / "capture").resolve())
    assert recorded_location(recorded_path(tmp_path / "capture")) == (tmp_path / "capture").resolve()
    assert recorded_path("") == ""


def test_harness_records_write_no_absolute_project_paths() -> None:
    run = PROJECT_ROOT / "data" / "tables_standard" / "runs" / "room" / "full" / "seed0-abc"
    r = RunResult("room", "full", 0, "ok", str(run), "abc", dataset=str(PROJECT_ROOT / "data" / "standard" / "room"),
                  stage2_from=str(run.parent / "seed0-def"))
    d = r.to_json()
    assert d["run_dir"] == "data/tables_standard/runs/room/full/seed0-abc"
    assert d["dataset"] == "data/standard/room" and d["stage2_from"] == "data/tables_standard/runs/room/full/seed0-def"
    assert str(PROJECT_ROOT) not in repr(d)
