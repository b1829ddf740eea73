"""`contact-sheet` on the real demo dataset: which frames it shows, and the PNG it writes."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from generator.contact_sheet import (
    COLUMNS,
    stretch,
    find_datasets,
    main,
    make_contact_sheet,
    pick_rows,
)
from contracts.errors import DatasetError

pytestmark = pytest.mark.blender


def test_rows_are_first_middle_last_with_nearest_thermal(demo_dataset: Path) -> None:
    rgb = json.loads((demo_dataset / "transforms_rgb.json").read_text())["frames"]
    thermal = json.loads((demo_dataset / "transforms_thermal.json").read_text())["frames"]
    rows = pick_rows(demo_dataset)
    assert [r.rgb_stem for r in rows] == [rgb[0]["file_stem"], rgb[(len(rgb) - 1) // 2]["file_stem"],
                                          rgb[-1]["file_stem"]]
    for row in rows:
        gaps = [abs(f["time"] - row.time) for f in thermal]
        chosen = next(f for f in thermal if f["file_stem"] == row.thermal_stem)
        assert abs(chosen["time"] - row.time) == pytest.approx(min(gaps))


def test_sheet_is_written_and_shows_the_data(demo_dataset: Path, tmp_path: Path) -> None:
    out = make_contact_sheet(demo_dataset, tmp_path / "demo.png")
    image = np.asarray(Image.open(out).convert("RGB"), dtype=float)
    height, width = image.shape[:2]
    assert width > height > 200
    assert image.std() > 20.0
    rgb = np.asarray(Image.open(demo_dataset / "rgb" / "smoky" / "0000.png"), dtype=float)
    panel_aspect = (width / len(COLUMNS)) / (height / 3)
    assert panel_aspect == pytest.approx(rgb.shape[1] / rgb.shape[0], rel=0.35)


def test_cli_writes_one_png_per_dataset_in_a_benchmark_folder(demo_dataset: Path, tmp_path: Path) -> None:
    bench = tmp_path / "bench"
    for name in ("a", "b"):
        shutil.copytree(demo_dataset, bench / name)
    (bench / "not_a_dataset").mkdir()
    assert [p.name for p in find_datasets(bench)] == ["a", "b"]
    assert main([str(bench), "--out", str(tmp_path / "sheets")]) == 0
    assert sorted(p.name for p in (tmp_path / "sheets").iterdir()) == ["a.png", "b.png"]


def test_missing_passes_show_as_blank_panels(demo_dataset: Path, tmp_path: Path) -> None:
    partial = tmp_path / "partial"
    shutil.copytree(demo_dataset, partial)
    shutil.rmtree(partial / "thermal")
    (partial / "transforms_thermal.json").unlink()
    assert all(r.thermal_stem is None for r in pick_rows(partial))
    assert make_contact_sheet(partial, tmp_path / "partial.png").is_file()


def test_bad_inputs_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="neither a dataset"):
        find_datasets(tmp_path)
    with pytest.raises(DatasetError, match="no such folder"):
        find_datasets(tmp_path / "nowhere")
    assert main([str(tmp_path), "--out", str(tmp_path / "o")]) == 2


def test_stretch_ignores_invalid_pixels_and_never_collapses() -> None:
    depth = np.zeros((10, 10))
    depth[:5] = np.linspace(2.0, 4.0, 50).reshape(5, 10)
    lo, hi = stretch([depth], [depth > 0])
    assert 2.0 <= lo < 2.1 and 3.9 < hi <= 4.0
    lo, hi = stretch([np.full((4, 4), 7.0)])
    assert (lo, hi) == (7.0, 8.0)
    assert stretch([]) == (0.0, 1.0)
