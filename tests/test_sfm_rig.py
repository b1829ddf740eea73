"""Thermal poses from the rig: SLERP and linear interpolation of the RGB trajectory, and the
RGB→thermal extrinsic, against analytic cases, scipy's Slerp and the generator's own rig; the rig
rotation estimate; and the Sim(3) the SfM benchmark scores with."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from benchmarks.sfm_poses import align, ate_rmse_m, pose_errors
from contracts.errors import DatasetError
from generator.rig import look_at, thermal_pose
from scenes.cameras import c2w_gl_to_viewmat, camera_center
from scenes.rig import (RigExtrinsic, apply_extrinsic, estimate_rig_rotation, interpolate_trajectory, parse_rig, slerp,
                        thermal_from_rig)


def _viewmat(rotation: np.ndarray, centre: np.ndarray) -> np.ndarray:
    v = np.eye(4)
    v[:3, :3] = rotation
    v[:3, 3] = -rotation @ centre
    return v


def _rot_z(deg: float) -> np.ndarray:
    return Rotation.from_euler("z", deg, degrees=True).as_matrix()


def test_slerp_matches_scipy_on_random_rotations() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        r0, r1 = Rotation.random(2, random_state=rng.integers(1 << 30)).as_matrix()
        w = float(rng.uniform())
        ref = Slerp([0.0, 1.0], Rotation.from_matrix([r0, r1]))([w]).as_matrix()[0]
        assert np.abs(slerp(r0, r1, w) - ref).max() < 1e-9


def test_slerp_end_points_and_half_turn() -> None:
    r0 = _rot_z(10.0)
    r1 = r0 @ Rotation.from_rotvec([math.pi, 0.0, 0.0]).as_matrix()
    assert np.allclose(slerp(r0, r1, 0.0), r0) and np.allclose(slerp(r0, r1, 1.0), r1)
    half = slerp(r0, r1, 0.5)
    assert np.allclose(half, r0 @ Rotation.from_rotvec([math.pi / 2, 0.0, 0.0]).as_matrix(), atol=1e-6)


def test_interpolation_is_slerp_and_linear_between_frames() -> None:
    # Frames at 0, 1 and 3 s; rotation about z 0, 30, 90 degrees; centres on a bent line.
    times = np.array([1.0, 0.0, 3.0])  # unsorted on purpose
    angles = {0.0: 0.0, 1.0: 30.0, 3.0: 90.0}
    centres = {0.0: np.array([0.0, 0.0, 0.0]), 1.0: np.array([1.0, 0.0, 0.0]), 3.0: np.array([1.0, 2.0, 0.0])}
    views = np.stack([_viewmat(_rot_z(angles[t]), centres[t]) for t in times])
    at = np.array([0.0, 0.5, 1.0, 2.5, 3.0])
    out = interpolate_trajectory(views, times, at)
    for v, t in zip(out, at):
        if t <= 1.0:
            deg, c = 30.0 * t, np.array([t, 0.0, 0.0])
        else:
            w = (t - 1.0) / 2.0
            deg, c = 30.0 + 60.0 * w, np.array([1.0, 2.0 * w, 0.0])
        assert np.allclose(v[:3, :3], _rot_z(deg), atol=1e-12)
        assert np.allclose(camera_center(v), c, atol=1e-12)


def test_interpolation_refuses_to_extrapolate() -> None:
    views = np.stack([_viewmat(np.eye(3), np.zeros(3)), _viewmat(np.eye(3), np.ones(3))])
    ok = interpolate_trajectory(views, np.array([0.0, 1.0]), np.array([1.05]), tolerance=0.1)
    assert np.allclose(camera_center(ok[0]), np.ones(3))
    with pytest.raises(ValueError, match="outside the trajectory's times"):
        interpolate_trajectory(views, np.array([0.0, 1.0]), np.array([1.2]), tolerance=0.1)


def test_extrinsic_matches_the_generators_rig() -> None:
    """The generator places the thermal camera ``baseline`` away in the RGB camera's Blender axes,
    looking the same way; our extrinsic in OpenCV axes must give the same pose."""
    rng = np.random.default_rng(0)
    for _ in range(5):
        c2w = look_at(rng.normal(size=3) * 3, rng.normal(size=3) * 0.3)
        baseline_gl = rng.normal(size=3) * 0.1
        expected = c2w_gl_to_viewmat(thermal_pose(c2w, tuple(baseline_gl)))
        got = apply_extrinsic(c2w_gl_to_viewmat(c2w)[None], np.eye(3), baseline_gl * np.array([1.0, -1.0, -1.0]))[0]
        assert np.allclose(got, expected, atol=1e-12)


def test_extrinsic_rotation_and_lever_compose() -> None:
    """A thermal camera turned 90 degrees about the RGB camera's y axis, 0.1 to its right: a world
    point maps to thermal camera coordinates that the definition x_rgb = R x_thermal + lever
    takes back to its RGB camera coordinates, and the centres differ by the lever."""
    rot = Rotation.from_euler("y", 90.0, degrees=True).as_matrix()
    lever = np.array([0.1, 0.0, 0.0])
    rgb = _viewmat(_rot_z(20.0), np.array([1.0, 2.0, 3.0]))
    th = apply_extrinsic(rgb[None], rot, lever)[0]
    x_world = np.linalg.inv(rgb) @ np.array([0.3, -0.2, 2.0, 1.0])  # a point in front of the RGB camera
    x_rgb = (rgb @ x_world)[:3]
    x_th = (th @ x_world)[:3]
    assert np.allclose(rot @ x_th + lever, x_rgb, atol=1e-12)
    assert np.allclose(camera_center(th), camera_center(rgb) + rgb[:3, :3].T @ lever, atol=1e-12)


def test_thermal_from_rig_notes_what_it_assumes() -> None:
    views = np.stack([_viewmat(_rot_z(a), np.array([a / 10, 0.0, 0.0])) for a in (0.0, 10.0, 20.0)])
    times = np.array([0.0, 1.0, 2.0])
    _, notes = thermal_from_rig(views, times, np.array([0.5, 1.5]), None)
    assert len(notes) == 1 and "not given" in notes[0] and "assumed" in notes[0]
    rig = RigExtrinsic(np.eye(3), np.array([0.06, 0.0, 0.0]))
    out, notes = thermal_from_rig(views, times, np.array([0.5]), rig)
    assert "not applied" in notes[0] and np.allclose(camera_center(out[0]), [0.5, 0.0, 0.0])
    out, notes = thermal_from_rig(views, times, np.array([0.5]), RigExtrinsic(np.eye(3), np.array([0.06, 0, 0]), 0.5))
    assert notes == []
    assert np.allclose(camera_center(out[0]), [0.5, 0.0, 0.0] + _rot_z(5.0).T @ [0.12, 0.0, 0.0])


@pytest.mark.parametrize("rig, field", [
    ({"lever_arm_m": [0.1, 0]}, "rig.lever_arm_m"),
    ({"thermal_rotation": [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "lever_arm_m": [0, 0, 0]}, "rig.thermal_rotation"),
    ({"thermal_rotation": "identity", "lever_arm_m": [0, 0, 0]}, "rig.thermal_rotation"),
    ({}, "rig.lever_arm_m"),
    ({"lever_arm_m": [0, 0, 0], "metres_per_unit": -1}, "rig.metres_per_unit"),
])
def test_parse_rig_names_the_bad_field(rig: dict, field: str, tmp_path: Path) -> None:
    source = tmp_path / "capture.json"
    source.write_text(json.dumps({"rig": rig}))
    with pytest.raises(DatasetError, match=f"capture.json: field '{field}'"):
        parse_rig({"rig": rig}, source)
    assert parse_rig({}, source) is None


def _orbit(n: int, radius: float = 2.0, height: float = 1.0, sweep_deg: float = 150.0) -> np.ndarray:
    angles = np.radians(np.linspace(0.0, sweep_deg, n))
    return np.stack([c2w_gl_to_viewmat(look_at(np.array([radius * math.cos(a), radius * math.sin(a), height]),
                                               np.zeros(3))) for a in angles])


def _other_world(views: np.ndarray, scale: float, rotation: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """The same cameras in a world x' = (Rᵀ (x − shift)) / scale: what a separate SfM run gives."""
    out = []
    for v in views:
        r, c = v[:3, :3], camera_center(v)
        out.append(_viewmat(r @ rotation, rotation.T @ (c - shift) / scale))
    return np.stack(out)


def test_rig_rotation_is_recovered_from_a_separate_thermal_solution() -> None:
    rgb = _orbit(30)
    times = np.linspace(0.0, 3.0, 30)
    th_times = np.linspace(0.05, 2.95, 20)
    rig = Rotation.from_rotvec(np.radians([2.0, -3.0, 1.5])).as_matrix()
    truth = apply_extrinsic(interpolate_trajectory(rgb, times, th_times), rig, np.zeros(3))
    own = _other_world(truth, 0.37, Rotation.from_rotvec([0.3, -1.1, 0.4]).as_matrix(), np.array([4.0, -2.0, 1.0]))
    est = estimate_rig_rotation(rgb, times, own, th_times)
    assert est.frames == 20 and est.residual_deg < 1e-4  # arccos near 1 resolves ~1e-6 degrees
    assert np.abs(est.rotation - rig).max() < 1e-6


def test_rig_rotation_on_a_straight_path_is_refused() -> None:
    rgb = np.stack([c2w_gl_to_viewmat(look_at(np.array([x, -3.0, 2.0]), np.array([x, 0.0, 0.0])))
                    for x in np.linspace(-2, 2, 10)])
    times = np.arange(10.0)
    with pytest.raises(ValueError, match="straight line"):
        estimate_rig_rotation(rgb, times, apply_extrinsic(rgb, np.eye(3), np.zeros(3)), times)


def test_a_sideways_lever_on_an_orbit_biases_the_rig_rotation_by_its_angle() -> None:
    """The documented limit: on a look-at orbit a lever along the camera's x axis moves every
    thermal centre along the path, which reads as a turn of the whole trajectory about the orbit's
    axis, so the estimate is off by about atan(lever / radius) about the camera's vertical."""
    rgb = _orbit(30, radius=2.0, height=0.0)
    times = np.linspace(0.0, 3.0, 30)
    th_times = np.linspace(0.05, 2.95, 20)
    truth = apply_extrinsic(interpolate_trajectory(rgb, times, th_times), np.eye(3), np.array([0.06, 0.0, 0.0]))
    est = estimate_rig_rotation(rgb, times, truth, th_times)
    angle = math.degrees(Rotation.from_matrix(est.rotation).magnitude())
    assert angle == pytest.approx(math.degrees(math.atan(0.06 / 2.0)), rel=0.05)
    axis = Rotation.from_matrix(est.rotation).as_rotvec() / math.radians(angle)
    assert abs(axis[1]) > 0.99  # the camera's y axis: the orbit's axis seen from a level camera


def test_the_benchmarks_alignment_undoes_a_similarity_even_on_a_straight_path() -> None:
    """Scoring SfM poses needs the Sim(3) onto the truth; on a straight path the centres alone
    leave the rotation about the path free, the orientations fix it."""
    line = np.stack([c2w_gl_to_viewmat(look_at(np.array([x, -3.0, 2.0]), np.array([x, 0.0, 0.0])))
                     for x in np.linspace(-2, 2, 10)])
    for ref in (_orbit(12), line):
        est = _other_world(ref, 0.4, Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix(), np.array([1.0, 2.0, 3.0]))
        sim = align(est, ref)
        assert sim.scale == pytest.approx(0.4)
        errs = pose_errors(est, ref, sim, 1.0)
        assert errs["rot_max_deg"] < 1e-4 and errs["centre_rmse_m"] < 1e-9


def test_the_trajectory_error_is_zero_for_a_similarity_and_the_least_squares_optimum() -> None:
    """The ATE fits the Sim(3) to the centres alone: zero where the estimate is the truth in
    another frame, and never above the centre RMSE after the orientation-led alignment, which is
    one Sim(3) among those it minimises over."""
    ref = _orbit(12)
    est = _other_world(ref, 0.4, Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix(), np.array([1.0, 2.0, 3.0]))
    assert ate_rmse_m(est, ref) < 1e-9
    rng = np.random.default_rng(5)
    for _ in range(10):
        noisy = est.copy()
        for v in noisy:
            centre = camera_center(v) + rng.normal(0.0, 0.05, 3)
            v[:3, :3] = Rotation.from_rotvec(rng.normal(0.0, 0.02, 3)).as_matrix() @ v[:3, :3]
            v[:3, 3] = -v[:3, :3] @ centre
        ate = ate_rmse_m(noisy, ref)
        oriented = pose_errors(noisy, ref, align(noisy, ref), 1.0)["centre_rmse_m"]
        assert 0.0 < ate <= oriented + 1e-12
