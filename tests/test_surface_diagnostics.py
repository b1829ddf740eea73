"""The de-smoked surface's diagnostics (smokeseer/evaluation/scoring.surface_diagnostics): a colour
cast on the smoky pixels, the share of pixels the surface does not cover, the score on the surface's
pixels with the environment and on black."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from contracts.results_format import ResultsFormatError, surface_diagnostics as check
from smokeseer.evaluation.scoring import TestRenders as Renders, surface_diagnostics


def _scene(clean: np.ndarray | None, masks: np.ndarray | None, depth: np.ndarray | None = None) -> SimpleNamespace:
    return SimpleNamespace(rgb=SimpleNamespace(indices=lambda split: [0, 1], clean=clean, masks=masks, depth=depth))


def test_an_analytic_cast_coverage_and_background() -> None:
    rng = np.random.default_rng(0)
    clean = rng.uniform(0.2, 0.8, (2, 8, 10, 3))
    masks = np.zeros((2, 8, 10))
    masks[0, :4] = 1.0  # 40 smoky pixels in view 0, 20 in view 1
    masks[1, :2] = 1.0
    surface = clean.copy()
    surface[masks > 0.5] += np.array([0.1, 0.0, -0.05])  # the cast, on the smoky pixels only
    alpha = np.ones((2, 8, 10))
    alpha[0, :, :5] = 0.5  # half of view 0 lets the environment through; view 1 none
    depth = np.full((2, 8, 10), 3.0)
    depth[:, 6:] = 0.0  # the bottom two rows are sky: no surface in the clean depth
    surface[:, 6:] = 0.0  # the surface render there is far off, and must not count
    on_black = clean + 0.1  # off by 0.1 on the surface's pixels: 20 dB there
    on_black[:, 6:] = 1.0
    renders = Renders(["0", "1"], list(surface), [np.zeros((8, 10))] * 2, [None, None], list(alpha), list(on_black))
    d = surface_diagnostics(renders, _scene(clean, masks, depth))
    assert d["smoky_pixels"] == 60
    assert d["colour_bias_smoky"] == pytest.approx([0.1, 0.0, -0.05], abs=1e-12)
    assert d["colour_bias_smoky_max"] == pytest.approx(0.1)
    assert d["surface_alpha_under_0_9"] == pytest.approx(0.25)
    assert d["psnr_surface_pixels_on_black"] == pytest.approx(20.0)
    # with the environment: view 0's 40 smoky pixels off by (0.1, 0, -0.05) among its 60 surface pixels,
    # view 1's 20; the PSNR is the mean of the two views'
    per_view = [10 * np.log10(1 / (n * (0.01 + 0.0025) / (60 * 3))) for n in (40, 20)]
    assert d["psnr_surface_pixels"] == pytest.approx(np.mean(per_view), abs=1e-9)
    assert surface_diagnostics(renders, _scene(clean, None, depth))["colour_bias_smoky"] is None  # no mask, no cast
    no_depth = surface_diagnostics(renders, _scene(clean, masks))
    assert no_depth["psnr_surface_pixels"] is None and no_depth["psnr_surface_pixels_on_black"] is None
    assert surface_diagnostics(renders, _scene(None, masks)) is None  # no ground truth, nothing to say


def test_the_contract_checks_the_record(tmp_path: Path) -> None:
    good = {"colour_bias_smoky": [0.1, 0.0, -0.05], "smoky_pixels": 60, "colour_bias_smoky_max": 0.1,
            "surface_alpha_under_0_9": 0.25, "psnr_surface_pixels": 24.0, "psnr_surface_pixels_on_black": 20.0}
    before = {**{k: v for k, v in good.items() if not k.startswith("psnr")}, "psnr_black_background": 20.0}
    path = tmp_path / "metrics.json"
    assert check({"surface_diagnostics": good}, path) == good
    assert check({"surface_diagnostics": before}, path) == before  # trainer 5e0f3ef6's runs
    assert check({"surface_diagnostics": {**good, "psnr_surface_pixels": None}}, path)  # no clean depth
    assert check({}, path) is None  # a run from before the field
    with pytest.raises(ResultsFormatError, match="colour_bias_smoky' must be 3 numbers"):
        check({"surface_diagnostics": {**good, "colour_bias_smoky": [0.1]}}, path)
    for record, key in ((good, "psnr_surface_pixels_on_black"), (before, "psnr_black_background")):
        with pytest.raises(ResultsFormatError, match="non-finite|finite"):
            check({"surface_diagnostics": {**record, key: float("nan")}}, path)
    with pytest.raises(ResultsFormatError, match="missing field 'surface_diagnostics.smoky_pixels'"):
        check({"surface_diagnostics": {k: v for k, v in good.items() if k != "smoky_pixels"}}, path)
    with pytest.raises(ResultsFormatError, match="missing field 'surface_diagnostics.psnr_surface_pixels_on_black'"):
        check({"surface_diagnostics": {k: v for k, v in good.items() if k != "psnr_surface_pixels_on_black"}}, path)
