"""The dataset's thermal curve (scenes.thermal_scale): checked against the empirical CDF, a
hand-made plateau case, its own inverse, and on a loaded dataset's smoky and clean frames."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contracts.imageio import read_png
from scenes.images import gray
from scenes.load import load_scene
from scenes.thermal_scale import EQUALISE_BINS, PLATEAU, ThermalScaleSpec, crowded_fraction, fit_thermal_scale
from tests.test_smokeseer_data import write_splat_dataset


def _room_like(rng: np.random.Generator) -> np.ndarray:
    """Counts of a room: 80 % a wall at one temperature with sensor noise, 15 % furniture
    spread over a few hundred counts, 5 % a hot grill far above everything else."""
    n = 200_000
    wall = rng.normal(3000.0, 4.0, int(0.80 * n))
    furniture = rng.uniform(2800.0, 3300.0, int(0.15 * n))
    grill = rng.uniform(9000.0, 12000.0, n - len(wall) - len(furniture))
    return rng.permutation(np.concatenate([wall, furniture, grill])).reshape(50, 40, 100)


def test_linear_range_ignores_a_small_hot_object() -> None:
    rng = np.random.default_rng(0)
    stack = rng.uniform(5000.0, 5600.0, size=(6, 40, 50))
    stack[:, :3, :3] = 11000.0  # a heater: 0.36 % of the pixels
    scale = fit_thermal_scale(stack, "linear")
    norm = scale.apply(stack)
    lo, hi = scale.raw_range
    assert 5000.0 <= lo < 5010.0 and 5590.0 < hi <= 5600.0
    inner = norm[:, 3:, 3:]
    assert np.percentile(inner, 99) - np.percentile(inner, 1) > 0.95
    assert norm.min() == 0.0 and norm.max() == 1.0 and np.all(norm[:, :3, :3] == 1.0)
    np.testing.assert_allclose(inner, np.clip((stack[:, 3:, 3:] - lo) / (hi - lo), 0, 1), atol=1e-6)


def test_equalised_is_the_cdf_where_no_bin_is_clipped() -> None:
    """Without a crowded bin the curve is the empirical CDF, so uniform counts map to ranks."""
    rng = np.random.default_rng(1)
    stack = rng.uniform(100.0, 900.0, size=(4, 60, 80))
    scale = fit_thermal_scale(stack, "equalised")
    mapped = scale.apply(stack).ravel()
    ranks = np.argsort(np.argsort(stack.ravel())) / (stack.size - 1)
    assert np.abs(mapped - ranks).max() < 2.0 / EQUALISE_BINS + 0.01


def test_equalised_spreads_a_crowded_scene_and_caps_the_wall() -> None:
    rng = np.random.default_rng(2)
    stack = _room_like(rng)
    linear, equalised = fit_thermal_scale(stack, "linear"), fit_thermal_scale(stack, "equalised")
    lin, eq = linear.apply(stack), equalised.apply(stack)
    wall = (stack > 2980.0) & (stack < 3020.0)
    # under the linear range the grill sets the top and the whole room sits in a sliver; equalised,
    # what is not the wall spreads out (the wall is one temperature, a sliver under any curve)
    assert crowded_fraction(lin) > 0.9 and crowded_fraction(lin[~wall]) > 0.7
    assert crowded_fraction(eq[~wall]) < 0.3
    # the wall's single temperature cannot take the range: its bins are capped at the plateau
    share_cap = PLATEAU / EQUALISE_BINS
    bins_over_wall = np.ceil(40.0 / ((stack.max() - stack.min()) / EQUALISE_BINS)) + 1
    clipped_total = np.minimum(np.histogram(stack, EQUALISE_BINS)[0], PLATEAU * stack.size / EQUALISE_BINS).sum()
    assert eq[wall].max() - eq[wall].min() <= bins_over_wall * share_cap * stack.size / clipped_total + 1e-6
    # the furniture, 15 % of the pixels, keeps its contrast instead of a few percent of the range
    furniture = (stack > 3100.0) & (stack < 3300.0)
    assert eq[furniture].max() - eq[furniture].min() > 5 * (lin[furniture].max() - lin[furniture].min())
    assert np.all(np.diff(equalised.levels) >= 0) and equalised.levels[0] == 0 and equalised.levels[-1] == 1


@pytest.mark.parametrize("kind", ["linear", "equalised"])
def test_invert_returns_raw_counts(kind: str) -> None:
    rng = np.random.default_rng(3)
    stack = _room_like(rng)
    scale = fit_thermal_scale(stack, kind)
    lo, hi = scale.raw_range
    inside = stack[(stack > lo) & (stack < hi)]
    tolerance = (hi - lo) / EQUALISE_BINS if kind == "equalised" else 1e-3 * (hi - lo)
    # an occupied bin's counts come back inside that bin
    assert np.abs(scale.invert(scale.apply(inside)) - inside).max() <= tolerance + 1e-6
    assert np.all(np.isfinite(scale.invert(np.array([-0.5, 0.0, 0.5, 1.0, 1.5]))))


@pytest.mark.parametrize("kind", ["linear", "equalised"])
def test_constant_frames_stay_finite(kind: str) -> None:
    scale = fit_thermal_scale(np.full((2, 4, 4), 7.0), kind)
    mapped = scale.apply(np.full((2, 4, 4), 7.0))
    assert scale.raw_range[1] > scale.raw_range[0] and np.all(np.isfinite(mapped))


def test_unknown_kind_names_the_field() -> None:
    with pytest.raises(ValueError, match="thermal_scale: 'gamma' is not one of linear, equalised"):
        fit_thermal_scale(np.ones((2, 2)), "gamma")


def test_loader_maps_smoky_and_clean_frames_through_one_curve(tmp_path: Path) -> None:
    ds = write_splat_dataset(tmp_path / "ds", n_rgb=4, n_thermal=4)
    linear = load_scene(ds, all_ground_truth=True)
    equalised = load_scene(ds, thermal_scale=ThermalScaleSpec("equalised"), all_ground_truth=True)
    assert linear.thermal.scale.kind == "linear" and equalised.thermal.scale.kind == "equalised"
    np.testing.assert_array_equal(linear.rgb.images, equalised.rgb.images)
    stems = [f.file_stem for f in equalised.thermal.frames]
    smoky = np.stack([gray(read_png(ds / "thermal" / "smoky" / f"{s}.png")) for s in stems])
    clean = np.stack([gray(read_png(ds / "thermal" / "clean" / f"{s}.png")) for s in stems])
    scale = equalised.thermal.scale
    np.testing.assert_allclose(equalised.thermal.images[..., 0], scale.apply(smoky), atol=1e-6)
    np.testing.assert_allclose(equalised.thermal.clean[..., 0], scale.apply(clean), atol=1e-6)
    # the same count means the same value in the smoky and the clean frames
    same = smoky == clean
    assert same.any()
    np.testing.assert_array_equal(equalised.thermal.images[..., 0][same], equalised.thermal.clean[..., 0][same])
    assert 0.0 <= equalised.thermal.images.min() and equalised.thermal.images.max() <= 1.0


def test_a_share_mixes_the_two_curves() -> None:
    rng = np.random.default_rng(4)
    stack = _room_like(rng)
    linear, equalised = fit_thermal_scale(stack, "linear"), fit_thermal_scale(stack, "equalised")
    mixed = fit_thermal_scale(stack, "equalised", 0.25)
    np.testing.assert_allclose(mixed.apply(stack), 0.25 * equalised.apply(stack) + 0.75 * linear.apply(stack),
                               atol=1e-5)
    assert np.all(np.diff(mixed.levels) >= 0) and mixed.record(mixed.apply(stack))["equalised_share"] == 0.25
    inside = stack[(stack > 2800.0) & (stack < 3300.0)]
    assert np.abs(mixed.invert(mixed.apply(inside)) - inside).max() < 0.01
    with pytest.raises(ValueError, match=r"thermal_equalised_share: must be in \(0, 1\], got 0"):
        fit_thermal_scale(stack, "equalised", 0.0)
