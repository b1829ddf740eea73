"""The haze-line smoke colour: line fitting and meeting point against colours made with a known
smoke colour, the multi-view bookkeeping against an exact pixel shift, and the refusals."""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks.smoke_colour_decisions import decision
from scenes.cameras import backproject
from smokeseer.stage1.haze_lines import (HazeLineSettings, estimate_smoke_colour, fit_lines, meeting_point, observations,
                                         refusal)

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
    assert est.colour is not None and est.meeting_fraction > 0.9
    np.testing.assert_allclose(est.colour, SMOKE, atol=0.01)


def test_a_bright_estimate_is_refused_above_the_brightness_bound_only() -> None:
    rng = np.random.default_rng(3)
    images, depths, valid, vms, ks = _static_frames(rng.uniform(0.2, 0.9, (20, H, W)), rng)
    mean = float(np.mean(SMOKE))
    below = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0),
                                  HazeLineSettings(max_brightness=mean - 0.02))
    assert below.colour is None and below.meeting_fraction > 0.9 and "a bright smoke colour" in below.reason
    above = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0),
                                  HazeLineSettings(max_brightness=mean + 0.02))
    np.testing.assert_allclose(above.colour, SMOKE, atol=0.01)
    np.testing.assert_array_equal(below.meeting, above.colour)   # refused for its brightness, still met


def test_estimate_refuses_smoke_that_never_changes() -> None:
    rng = np.random.default_rng(4)
    images, depths, valid, vms, ks = _static_frames(np.full((20, H, W), 0.5), rng)
    est = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0))
    assert est.colour is None and est.lines == 0 and "fewer than" in est.reason


def test_estimate_refuses_lines_that_do_not_meet() -> None:
    """Colours that vary along a random direction per pixel (shading, not smoke) meet nowhere."""
    rng = np.random.default_rng(5)
    base = rng.uniform(0.3, 0.7, (H, W, 3))
    direction = rng.normal(size=(H, W, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    images = base + rng.uniform(-0.2, 0.2, (20, H, W, 1)) * direction
    est = estimate_smoke_colour(images, np.full((20, H, W), 2.0), np.ones((20, H, W), bool),
                                np.stack([_viewmat(0.0)] * 20), np.stack([K] * 20), np.random.default_rng(0))
    assert est.colour is None and est.lines >= 100 and "do not meet" in est.reason and est.meeting is None


@pytest.mark.parametrize("spread", [0.0, 1e-4])
def test_estimate_on_a_smokeless_sequence_is_a_refusal_not_nan(spread: float) -> None:
    rng = np.random.default_rng(6)
    images, depths, valid, vms, ks = _static_frames(np.ones((20, H, W)) - spread * rng.random((20, H, W)), rng)
    est = estimate_smoke_colour(images, depths, valid, vms, ks, np.random.default_rng(0))
    assert est.colour is None and est.meeting_fraction is None


@pytest.mark.parametrize("colour, met", [((0.7, 0.53, 0.42), 0.3),      # the lines do not meet
                                         ((0.7, 0.53, 0.42), 0.6),      # bright
                                         ((1.2, 0.5, 0.4), 0.6)])       # outside the cube
def test_the_decisions_table_reads_the_colour_back_from_every_refusal(colour: tuple, met: float) -> None:
    reason = refusal(np.array(colour), met, HazeLineSettings(max_brightness=0.5))
    assert reason
    stages = {"smoke_colour": {"haze_lines": {"colour": None, "lines": 120, "meeting_fraction": met, "refused": reason}}}
    got = decision(stages)
    assert not got["held"] and got["lines"] == 120
    assert [float(c) for c in got["colour"].split()] == pytest.approx(colour, abs=1e-3)


def test_a_dark_colour_whose_lines_meet_is_held() -> None:
    assert refusal(np.array((0.2, 0.2, 0.22)), 0.6, HazeLineSettings(max_brightness=0.5)) == ""
