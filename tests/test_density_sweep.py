"""The density sweep's arithmetic (eval.density_sweep) on cases worked by hand."""
from __future__ import annotations

import math

import numpy as np
import pytest

from eval.density_sweep import crossover, mean_optical_depth, paired_lead


def test_optical_depth_of_uniform_smoke_scales_with_k() -> None:
    alpha = 0.3
    for k in (0.0, 0.5, 1.0, 4.0):
        views = [np.full((6, 8), 1 - (1 - alpha) ** k, dtype=np.float32) for _ in range(3)]
        assert mean_optical_depth(views) == pytest.approx(-k * math.log(1 - alpha), rel=1e-6, abs=1e-9)
    assert math.isfinite(mean_optical_depth([np.ones((2, 2))]))  # opaque smoke: large, not inf
    with pytest.raises(ValueError):
        mean_optical_depth([])


def test_lead_pairs_seeds() -> None:
    lead = paired_lead({0: 20.0, 1: 21.0, 2: 22.0}, {0: 19.0, 1: 21.0, 3: 30.0})
    assert lead is not None and lead.seeds == (0, 1)
    assert lead.mean == pytest.approx(0.5) and lead.std == pytest.approx(math.sqrt(0.5))
    assert paired_lead({0: 1.0}, {1: 1.0}) is None
    assert paired_lead({0: 2.0}, {0: 1.0}).std is None


def test_crossover_interpolates_between_the_densities_around_it() -> None:
    assert crossover([2.0, 0.0, 1.0], [0.5, -1.0, -0.5]) == (pytest.approx(1.5), "crossing")
    assert crossover([0.0, 1.0], [0.0, 2.0]) == (None, "ahead throughout")
    assert crossover([0.0, 1.0], [-0.2, -2.0]) == (None, "behind throughout")
    assert crossover([0.0, 1.0], [0.2, -2.0]) == (None, "falls behind")
    at, how = crossover([0.0, 1.0, 2.0, 3.0], [-1.0, 1.0, -1.0, 2.0])
    assert at == pytest.approx(0.5) and how == "crossing, then behind again"
    with pytest.raises(ValueError):
        crossover([0.0], [])
