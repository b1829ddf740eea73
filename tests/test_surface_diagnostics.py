"""The de-smoked surface's diagnostics (smokeseer/evaluation/scoring.surface_diagnostics): a colour
cast on the smoky pixels, the share of pixels the surface does not cover, the score on black."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from contracts.results_format import ResultsFormatError, surface_diagnostics as check
from smokeseer.evaluation.scoring import TestRenders as Renders, surface_diagnostics


def _scene(clean: np.ndarray, masks: np.ndarray | None) -> SimpleNamespace:
    return SimpleNamespace(rgb=SimpleNamespace(indices=lambda split: [0, 1], clean=clean, masks=masks))


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
    renders = Renders(["0", "1"], list(surface), [np.zeros((8, 10))] * 2, [None, None], list(alpha),
                          [c + 0.1 for c in clean])  # on black: off by 0.1 everywhere, 20 dB
    d = surface_diagnostics(renders, _scene(clean, masks))
    assert d["smoky_pixels"] == 60
    assert d["colour_bias_smoky"] == pytest.approx([0.1, 0.0, -0.05], abs=1e-12)
    assert d["colour_bias_smoky_max"] == pytest.approx(0.1)
    assert d["surface_alpha_under_0_9"] == pytest.approx(0.25)
    assert d["psnr_black_background"] == pytest.approx(20.0)
    assert surface_diagnostics(renders, _scene(clean, None))["colour_bias_smoky"] is None  # no mask, no cast
    assert surface_diagnostics(renders, _scene(None, masks)) is None  # no ground truth, nothing to say


def test_the_contract_checks_the_record(tmp_path: Path) -> None:
    good = {"colour_bias_smoky": [0.1, 0.0, -0.05], "smoky_pixels": 60, "colour_bias_smoky_max": 0.1,
            "surface_alpha_under_0_9": 0.25, "psnr_black_background": 20.0}
    path = tmp_path / "metrics.json"
    assert check({"surface_diagnostics": good}, path) == good
    assert check({}, path) is None  # a run from before the field
    with pytest.raises(ResultsFormatError, match="colour_bias_smoky' must be 3 numbers"):
        check({"surface_diagnostics": {**good, "colour_bias_smoky": [0.1]}}, path)
    with pytest.raises(ResultsFormatError, match="non-finite|finite"):
        check({"surface_diagnostics": {**good, "psnr_black_background": float("nan")}}, path)
    with pytest.raises(ResultsFormatError, match="missing field 'surface_diagnostics.smoky_pixels'"):
        check({"surface_diagnostics": {k: v for k, v in good.items() if k != "smoky_pixels"}}, path)
