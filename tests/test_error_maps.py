"""benchmarks/error_maps.py: the surface's PSNR against an analytic case, the smoke column only
where asked for, and one clear line (no figure) where a render is missing."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.error_maps import panels
from contracts.imageio import write_png

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "error_maps.py"


def _scene(tmp_path: Path) -> tuple[Path, Path]:
    dataset, run = tmp_path / "dataset", tmp_path / "run"
    for folder, value in ((dataset / "rgb" / "clean", 51), (dataset / "rgb" / "smoky", 102),
                          (run / "renders" / "surface", 77)):
        folder.mkdir(parents=True)
        write_png(folder / "0004.png", np.full((6, 8, 3), value, np.uint8))
    return dataset, run


def test_psnr_is_the_analytic_one_and_the_smoke_column_is_optional(tmp_path: Path) -> None:
    dataset, run = _scene(tmp_path)
    images, psnr, psnr_input = panels(dataset, run, "0004", smoke=False)
    assert len(images) == 4
    assert math.isclose(psnr, 20 * math.log10(255 / 26), abs_tol=1e-6)
    assert math.isclose(psnr_input, 20 * math.log10(255 / 51), abs_tol=1e-6)
    assert np.allclose(images[-1], min(1.0, 4 * 26 / 255))


def test_a_missing_smoke_render_is_one_line_and_no_figure(tmp_path: Path) -> None:
    dataset, run = _scene(tmp_path)
    out = tmp_path / "fig.png"
    row = f"Full={dataset}:{run}:0004"
    refused = subprocess.run([sys.executable, str(SCRIPT), "--out", str(out), row], capture_output=True, text=True)
    assert refused.returncode != 0
    assert refused.stderr.strip().count("\n") == 0 and "renders/smoke/0004.png not found" in refused.stderr
    assert "--without-smoke" in refused.stderr and not out.exists()
    done = subprocess.run([sys.executable, str(SCRIPT), "--out", str(out), "--without-smoke", row],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert out.is_file() and [p.name for p in tmp_path.iterdir() if p.is_file()] == ["fig.png"]
