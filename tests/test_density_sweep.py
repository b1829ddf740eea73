"""The density sweep's arithmetic (eval.density_sweep) on cases worked by hand."""
from __future__ import annotations

import math

import numpy as np
import pytest

from eval.density_sweep import (crossover, frame_at_scale, mean_optical_depth, paired_lead, results_table,
                                sweep_checks)


def test_optical_depth_of_uniform_smoke_scales_with_k() -> None:
    alpha = 0.3
    for k in (0.0, 0.5, 1.0, 4.0):
        views = [np.full((6, 8), 1 - (1 - alpha) ** k, dtype=np.float32) for _ in range(3)]
        assert mean_optical_depth(views) == pytest.approx(-k * math.log(1 - alpha), rel=1e-6, abs=1e-9)
    assert math.isfinite(mean_optical_depth([np.ones((2, 2))]))  # opaque smoke: large, not inf
    with pytest.raises(ValueError):
        mean_optical_depth([])


def test_a_frame_at_another_density_follows_the_compositing_of_its_smoke() -> None:
    """A frame composited from a known clean frame J, smoke colour A and opacity α comes back at
    k = 1, becomes J at k = 0, and at k = 3 is J under opacity 1 − (1 − α)³ of the same colour;
    pixels with no smoke keep the k = 1 frame (its render noise is not the smoke's)."""
    rng = np.random.default_rng(0)
    clean = rng.uniform(0, 1, (5, 7, 3))
    colour = rng.uniform(0, 1, (5, 7, 3))
    alpha = rng.uniform(0.05, 0.95, (5, 7))
    alpha[0, 0] = 0.0
    smoky = (1 - alpha[..., None]) * clean + alpha[..., None] * colour
    smoky[0, 0] += 0.01  # noise where there is no smoke
    assert np.allclose(frame_at_scale(smoky, clean, alpha, 1.0), smoky)
    assert np.allclose(frame_at_scale(smoky, clean, alpha, 0.0)[1:], clean[1:])
    a3 = 1 - (1 - alpha[..., None]) ** 3
    expected = (1 - a3) * clean + a3 * colour
    expected[0, 0] = smoky[0, 0]
    assert np.allclose(frame_at_scale(smoky, clean, alpha, 3.0), expected)
    opaque = frame_at_scale(smoky, clean, np.full((5, 7), 1.0), 2.0)
    assert np.all(np.isfinite(opaque)) and opaque.min() >= 0 and opaque.max() <= 1
    with pytest.raises(ValueError):
        frame_at_scale(smoky, clean, alpha, -1.0)


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


def _row(scene: str, k: float, lead: float | None, rgb: float, std: float | None = 0.1, seeds: str = "0 1 2") -> dict:
    return {"scene": scene, "k": k, "lead_psnr": lead, "lead_psnr_std": std, "rgb-only_psnr": rgb,
            "full_seeds": seeds, "rgb-only_seeds": seeds}


def _holds(rows: list[dict]) -> list[str]:
    return [c.holds for c in sweep_checks(rows)]


def test_sweep_checks_on_a_sweep_that_meets_every_target() -> None:
    ks = (0.0, 0.5, 1.0, 2.0, 8.0)
    rows = [_row(sc, k, lead, rgb) for sc in ("a", "b", "c")
            for k, lead, rgb in zip(ks, (-0.05, 0.2, 0.9, 2.0, 3.5), (30.0, 26.0, 22.0, 19.0, 14.0))]
    assert _holds(rows) == ["yes", "yes", "yes", "yes"]


def test_sweep_checks_name_each_failure() -> None:
    ks = (0.0, 0.5, 1.0, 2.0, 8.0)
    good = [_row("a", k, lead, rgb) for k, lead, rgb in zip(ks, (0.0, 0.2, 0.9, 2.0, 3.5), (30, 26, 22, 19, 14))]
    # b: costs 0.3 dB with no smoke, its lead falls 1.0 dB from k 1 to 2 with a spread of
    # √(0.3² + 0.4²) = 0.5, and its densest k leaves RGB-only at 17 dB.
    b = [_row("b", 0.0, -0.3, 30), _row("b", 0.5, 0.5, 26), _row("b", 1.0, 1.5, 22, std=0.3),
         _row("b", 2.0, 0.5, 20, std=0.4), _row("b", 8.0, 3.2, 17)]
    checks = sweep_checks(good + b)
    assert [c.holds for c in checks] == ["no", "no", "no", "no"]  # coverage: two scenes, not three
    assert "b -0.30" in checks[1].measured
    assert "RGB-only above 16 dB" in checks[2].measured and "b k 8" in checks[2].measured
    assert "b: worst step k 1 → 2, lead +1.50 → +0.50 (spread 0.50)" in checks[3].measured
    # The same fall inside a wider spread (√(0.8² + 0.8²) = 1.13) is not a fall.
    b[2], b[3] = _row("b", 1.0, 1.5, 22, std=0.8), _row("b", 2.0, 0.5, 20, std=0.8)
    assert sweep_checks(good + b)[3].holds == "yes"


def test_sweep_checks_wait_for_what_has_not_run() -> None:
    rows = [_row("a", 0.0, None, 30.0, seeds=""), _row("a", 1.0, 0.4, 22.0, seeds="0")]
    checks = sweep_checks(rows)
    assert [c.holds for c in checks] == ["no", "not yet", "no", "not yet"]
    assert checks[1].left_out == "a"
    assert "a: 0 complete" in checks[0].measured


def test_results_table_orders_by_density_and_says_which_seeds_each_method_has() -> None:
    def row(scene: str, k: float, full: tuple, rgb: tuple, lead: float | None, seeds: tuple[str, str]) -> dict:
        return {"scene": scene, "k": k, "optical_depth": 0.5 * k, "input_psnr": 20.0 - k,
                "full_psnr": full[0], "full_psnr_std": full[1], "rgb-only_psnr": rgb[0], "rgb-only_psnr_std": rgb[1],
                "lead_psnr": lead, "full_seeds": seeds[0], "rgb-only_seeds": seeds[1]}
    lines = results_table([row("b", 2.0, (18.0, None), (None, None), None, ("0", "")),
                           row("b", 0.0, (30.004, 0.1), (30.5, 0.25), -0.496, ("0 1 2", "0 1 2")),
                           row("a", 2.0, (19.0, 0.3), (17.0, None), 2.0, ("0 1", "0"))])
    assert lines[2:] == ["| b | 0 | 0.00 | 20.00 | 30.50 ± 0.25 | 30.00 ± 0.10 | −0.50 | 0, 1, 2 |",
                         "| a | 2 | 1.00 | 18.00 | 17.00 | 19.00 ± 0.30 | +2.00 | 0 / 0, 1 |",
                         "| b | 2 | 1.00 | 18.00 | — | 18.00 | — | — / 0 |"]


def test_lpips_lead_is_rgb_only_minus_full_and_absent_where_a_seed_lacks_it() -> None:
    """benchmarks/density_sweep.py: LPIPS is lower-is-better, so Full's lead in it is RGB-only − Full,
    paired by seed (positive where Full is closer to the clean frames, as a positive PSNR lead is);
    a seed whose run has no LPIPS leaves that method with no mean and the scene with no lead."""
    from benchmarks.density_sweep import score_columns
    from eval.density_sweep import lpips_table

    def runs(psnr: list[float], lpips: list[float | None]) -> dict[int, dict]:
        return {s: {"psnr": p, "pooled_psnr": p, "ssim": 0.8, "lpips": q} for s, (p, q) in enumerate(zip(psnr, lpips))}

    scores = {("a", "full"): runs([22.0, 24.0], [0.30, 0.20]), ("a", "rgb-only"): runs([21.0, 21.0], [0.40, 0.40])}
    row = score_columns(scores, "a")
    assert row["lead_psnr"] == pytest.approx(2.0) and row["lead_lpips"] == pytest.approx(0.15)
    assert row["lead_lpips_std"] == pytest.approx(math.sqrt(2) * 0.05)
    assert row["full_lpips"] == pytest.approx(0.25) and row["rgb-only_lpips"] == pytest.approx(0.40)
    table = lpips_table([{"scene": "a", "k": 1.0, "optical_depth": 0.5, **row}])
    assert table[2] == "| a | 1 | 0.50 | 0.400 ± 0.000 | 0.250 ± 0.071 | +0.150 | 0, 1 |"
    scores[("a", "rgb-only")] = runs([21.0, 21.0], [0.40, None])
    row = score_columns(scores, "a")
    assert row["rgb-only_lpips"] is None and row["lead_lpips"] is None and row["full_lpips"] == pytest.approx(0.25)
    assert row["lead_psnr"] == pytest.approx(2.0)
    assert lpips_table([{"scene": "a", "k": 1.0, "optical_depth": 0.5, **row}])[2] == \
        "| a | 1 | 0.50 | — | 0.250 ± 0.071 | — | 0, 1 |"
