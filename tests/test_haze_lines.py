"""The haze-line smoke colour: line fitting and meeting point against colours made with a known
smoke colour, the multi-view bookkeeping against an exact pixel shift, the refusals, and the
trust, which must move with what the images say without a step; the table of every run's decision."""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks.smoke_colour_decisions import decision
from scenes.cameras import backproject
from smokeseer.stage1.haze_lines import (HazeLineSettings, estimate_smoke_colour, fit_lines, meeting_factors,
                                         meeting_point, observations,
                                         trust)

SMOKE = np.array([0.2, 0.3, 0.25])
F, W, H = 100.0, 64, 48
K = np.array([[F, 0.0, W / 2], [0.0, F, H / 2], [0.0, 0.0, 1.0]])


def _viewmat(camera_x: float) -> np.ndarray:
    """World to camera (OpenCV axes) for a camera at (camera_x, 0, 0) looking along +z."""
    vm = np.eye(4)
    vm[0, 3] = -camera_x
    return vm


def _static_frames(transmittance: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Frames of one camera over a textured plane at depth 2 under smoke of colour SMOKE."""
    n = transmittance.shape[0]
    surface = rng.uniform(0.0, 1.0, (H, W, 3))
    images = SMOKE + transmittance[..., None] * (surface - SMOKE)
    depths = np.full((n, H, W), 2.0)
    return images, depths, np.ones((n, H, W), bool), np.stack([_viewmat(0.0)] * n), np.stack([K] * n)


def test_lines_through_one_colour_meet_there() -> None:
    rng = np.random.default_rng(0)
    surfaces = rng.uniform(0.0, 1.0, (200, 3))
    t = rng.uniform(0.1, 0.9, (12, 200, 1))
    colours = SMOKE + t * (surfaces - SMOKE)
    seen = np.ones((12, 200), bool)
    means, dirs, weights = fit_lines(colours, seen, HazeLineSettings())
    assert len(means) == 200
    np.testing.assert_allclose(meeting_point(means, dirs, weights), SMOKE, atol=1e-9)
    noisy = colours + rng.normal(0.0, 0.005, colours.shape)
    means, dirs, weights = fit_lines(noisy, seen, HazeLineSettings())
    np.testing.assert_allclose(meeting_point(means, dirs, weights), SMOKE, atol=0.01)


def test_parallel_lines_have_no_meeting_point() -> None:
    means = np.random.default_rng(1).uniform(0.0, 1.0, (50, 3))
    dirs = np.tile(np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0), (50, 1))
    assert meeting_point(means, dirs, np.ones(50)) is None


def test_observations_follow_a_camera_shift_and_skip_hidden_points() -> None:
    """A camera moved by 4 * depth / f along x sees the plane's pixels 4 columns to the left."""
    rng = np.random.default_rng(2)
    first = rng.uniform(0.0, 1.0, (H, W, 3))
    second = np.zeros_like(first)
    second[:, :-4] = first[:, 4:]
    depths = np.full((2, H, W), 2.0)
    depths[1, :, :10] = 1.0  # something nearer hides these columns in the second frame
    uv = np.stack([rng.integers(0, W, 100), rng.integers(0, H, 100)], 1)
    points = backproject(depths[0, uv[:, 1], uv[:, 0]], uv, _viewmat(0.0), K)
    np.testing.assert_allclose(points[:, 2], 2.0)
    colours, seen = observations(points, np.stack([first, second]), depths, np.ones((2, H, W), bool),
                                 np.stack([_viewmat(0.0), _viewmat(4 * 2.0 / F)]), np.stack([K, K]), 0.03)
    assert seen[0].all()
    np.testing.assert_allclose(colours[0], first[uv[:, 1], uv[:, 0]])
    visible = (uv[:, 0] - 4 >= 10)
    assert (seen[1] == visible).all()
    np.testing.assert_allclose(colours[1, visible], first[uv[visible, 1], uv[visible, 0]])


def test_estimate_recovers_the_smoke_colour_of_moving_smoke() -> None:
    rng = np.random.default_rng(3)
    images, depths, valid, vms, ks = _static_frames(rng.uniform(0.2, 0.9, (20, H, W)), rng)
    est = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0))
    assert est.colour is not None and est.meeting_fraction > 0.9 and est.lines >= 400
    np.testing.assert_allclose(est.colour, SMOKE, atol=0.01)
    assert est.trust == 1.0 and est.reason == ""   # many lines, meeting, dark: held


def test_a_bright_estimate_loses_its_trust_over_the_brightness_ramp_only() -> None:
    """The same lines under ramps placed around the smoke's channel mean: full trust under the
    ramp, none over it, and the linear share inside it, with the colour and its meeting kept."""
    rng = np.random.default_rng(3)
    images, depths, valid, vms, ks = _static_frames(rng.uniform(0.2, 0.9, (20, H, W)), rng)
    mean = float(np.mean(SMOKE))
    by_ramp = {}
    for name, (zero, one) in {"over": (mean - 0.04, mean - 0.08), "inside": (mean + 0.01, mean - 0.03),
                              "under": (mean + 0.08, mean + 0.04)}.items():
        by_ramp[name] = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0),
                                              HazeLineSettings(max_brightness=zero, full_brightness=one))
        np.testing.assert_allclose(by_ramp[name].colour, SMOKE, atol=0.01)
        np.testing.assert_array_equal(by_ramp[name].meeting, by_ramp[name].colour)
    assert by_ramp["over"].trust == 0.0 and "channel mean" in by_ramp["over"].reason
    assert by_ramp["under"].trust == 1.0 and by_ramp["under"].reason == ""
    got = float(np.mean(by_ramp["inside"].colour))
    assert by_ramp["inside"].trust == pytest.approx((mean + 0.01 - got) / 0.04, abs=1e-9)


def test_the_surface_trust_reads_the_same_estimate_with_its_own_darkness_ramp() -> None:
    """The start's trust differs from the colour's only where its darkness factor reaches 1: the
    same colour, lines and meeting, full surface trust at a brighter channel mean."""
    rng = np.random.default_rng(3)
    images, depths, valid, vms, ks = _static_frames(rng.uniform(0.2, 0.9, (20, H, W)), rng)
    mean = float(np.mean(SMOKE))
    est = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0),
                                HazeLineSettings(max_brightness=mean + 0.04, full_brightness=mean - 0.04,
                                                 surface_full_brightness=mean - 0.02))
    got = float(np.mean(est.colour))
    assert est.trust == pytest.approx((mean + 0.04 - got) / 0.08, abs=1e-9)
    assert est.surface_trust == pytest.approx((mean + 0.04 - got) / 0.06, abs=1e-9)
    assert 0.0 < est.trust < est.surface_trust < 1.0


def test_trust_moves_without_a_step() -> None:
    """Along each input (lines, meeting fraction, brightness) the trust changes by at most its
    ramp's slope times the step: no threshold where one more line or a hair of colour flips the
    method (the food_plate cliff of docs/experiments/2026-12-01-stage2-rounding-and-the-colour-cliff.md:
    98 lines learned, 106 held)."""
    s = HazeLineSettings()
    dark = np.array([0.3, 0.3, 0.3])
    by_lines = [trust(dark, n, 0.9, s, s.full_brightness)[0] for n in range(s.min_lines, s.full_lines + 50)]
    assert by_lines[0] == 0.0 and by_lines[-1] == 1.0
    assert np.all(np.diff(by_lines) >= 0) and np.max(np.diff(by_lines)) <= 1.0 / (s.full_lines - s.min_lines) + 1e-12
    assert trust(dark, 106, 0.9, s, s.full_brightness)[0] == pytest.approx(6 / 300)
    mets = np.linspace(0.0, 1.0, 2001)
    by_met = np.array([trust(dark, 1000, m, s, s.full_brightness)[0] for m in mets])
    assert np.max(np.abs(np.diff(by_met))) <= (mets[1] - mets[0]) / (s.full_meeting_fraction - s.min_meeting_fraction) + 1e-9
    assert by_met[mets <= s.min_meeting_fraction].max() == 0.0 and by_met[mets >= s.full_meeting_fraction].min() == 1.0
    greys = np.linspace(0.0, 1.0, 2001)
    for full in (s.full_brightness, s.surface_full_brightness):
        by_grey = np.array([trust(np.full(3, g), 1000, 0.9, s, full)[0] for g in greys])
        assert np.all(np.diff(by_grey) <= 0) and by_grey[0] == 1.0 and by_grey[-1] == 0.0
        assert np.max(np.abs(np.diff(by_grey))) <= (greys[1] - greys[0]) / (s.max_brightness - full) + 1e-9
    value, why = trust(np.array([0.45, 0.45, 0.45]), 250, 0.25, s, 0.4)
    assert value == pytest.approx(0.5 * 0.5 * 0.5)
    assert "250 lines" in why and "0.25 of the lines meet" in why and "channel mean 0.45 (full at 0.4" in why


def test_the_meeting_weight_is_the_trust_without_its_darkness_ramp() -> None:
    """How far the meeting point places the smoke's density: the trust's line and meeting ramps
    alone, so a bright smoke whose colour is not held still has a meeting of full weight, and
    the weight moves without a step in the line count (0 at 100 lines, where an estimate begins)."""
    rng = np.random.default_rng(3)
    images, depths, valid, vms, ks = _static_frames(rng.uniform(0.2, 0.9, (20, H, W)), rng)
    mean = float(np.mean(SMOKE))
    bright = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0),
                                   HazeLineSettings(max_brightness=mean - 0.04, full_brightness=mean - 0.08))
    assert bright.trust == 0.0 and bright.meeting_weight == 1.0
    s = HazeLineSettings()
    weights = [float(np.prod(list(meeting_factors(n, 0.9, s).values()))) for n in range(s.min_lines, s.full_lines + 1)]
    assert weights[0] == 0.0 and weights[-1] == 1.0 and np.max(np.diff(weights)) <= 1.0 / (s.full_lines - s.min_lines) + 1e-12
    assert float(np.prod(list(meeting_factors(250, 0.25, s).values()))) == pytest.approx(0.5 * 0.5)


def test_estimate_refuses_smoke_that_never_changes() -> None:
    rng = np.random.default_rng(4)
    images, depths, valid, vms, ks = _static_frames(np.full((20, H, W), 0.5), rng)
    est = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0))
    assert est.colour is None and est.lines == 0 and "fewer than" in est.reason and est.trust == 0.0


def test_lines_that_do_not_meet_get_no_trust() -> None:
    """Colours that vary along a random direction per pixel (shading, not smoke) meet nowhere."""
    rng = np.random.default_rng(5)
    base = rng.uniform(0.3, 0.7, (H, W, 3))
    direction = rng.normal(size=(H, W, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    images = base + rng.uniform(-0.2, 0.2, (20, H, W, 1)) * direction
    est = estimate_smoke_colour(images, np.full((20, H, W), 2.0), np.ones((20, H, W), bool),
                                np.stack([_viewmat(0.0)] * 20), np.stack([K] * 20), np.random.default_rng(0))
    assert est.lines >= 100 and est.meeting_fraction < 0.2 and est.meeting is None and est.trust == 0.0
    assert est.meeting_weight == 0.0
    assert est.colour is not None and "0.02 of the lines meet (full at 0.3): 0.00" in est.reason


@pytest.mark.parametrize("spread", [0.0, 1e-4])
def test_estimate_on_a_smokeless_sequence_is_a_refusal_not_nan(spread: float) -> None:
    rng = np.random.default_rng(6)
    images, depths, valid, vms, ks = _static_frames(np.ones((20, H, W)) - spread * rng.random((20, H, W)), rng)
    est = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0))
    assert est.colour is None and est.meeting_fraction is None and est.trust == 0.0


@pytest.mark.parametrize("reason", ["the lines do not meet: under 0.2 of them pass within 0.03 of their nearest "
                                    "point [0.7, 0.53, 0.42]",
                                    "a bright smoke colour [0.7, 0.53, 0.42] (channel mean 0.55, over 0.5): a "
                                    "scattering smoke's radiance follows the light and the view",
                                    "the lines meet outside the colour cube, at [0.7, 0.53, 0.42]"])
def test_the_decisions_table_reads_the_colour_back_from_an_older_runs_refusal(reason: str) -> None:
    """Trainer f13fe3c1 and older recorded a refused colour only inside its reason."""
    stages = {"smoke_colour": {"haze_lines": {"colour": None, "lines": 120, "meeting_fraction": 0.3, "refused": reason}}}
    got = decision(stages)
    assert not got["held"] and got["trust"] == 0.0 and got["lines"] == 120
    assert [float(c) for c in got["colour"].split()] == pytest.approx((0.7, 0.53, 0.42), abs=1e-3)
    held = decision({"smoke_colour": {"haze_lines": {"colour": [0.2, 0.2, 0.2], "lines": 900, "meeting_fraction": 0.8,
                                                      "refused": None}}})
    assert held["held"] and held["trust"] == 1.0


def test_the_decisions_table_reads_a_trust() -> None:
    got = decision({"smoke_colour": {"haze_lines": {"colour": [0.4, 0.4, 0.4], "trust": 0.25, "lines": 250,
                                                     "meeting_fraction": 0.35, "limits": "250 lines"}}})
    assert got["trust"] == 0.25 and not got["held"] and got["colour_mean"] == 0.4


def test_decisions_table_carries_each_runs_test_scores(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """benchmarks/smoke_colour_decisions.py on two committed runs: PSNR and LPIPS as their records hold them."""
    from benchmarks import smoke_colour_decisions

    tables = Path(__file__).resolve().parents[1] / "data" / "tables_standard_avx2"
    out = tmp_path / "decisions.csv"
    monkeypatch.setattr(sys, "argv", ["smoke_colour_decisions.py", "--tables", str(tables), "--digest", "d65d2bcb",
                                      "--variants", "full", "--out", str(out)])
    smoke_colour_decisions.main()
    rows = list(csv.DictReader(out.open()))
    assert [r["seed"] for r in rows] == ["1", "2"]
    for row in rows:
        (run,) = tables.glob(f"runs/{row['scene']}/full/seed{row['seed']}-*/metrics.json")
        metrics = json.loads(run.read_text())["metrics"]
        assert float(row["test_lpips"]) == round(metrics["lpips"], 4) > 0
        assert float(row["test_psnr"]) == round(metrics["psnr"], 3)
