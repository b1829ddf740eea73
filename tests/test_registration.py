"""Cross-modal Sim(3) registration: recover a known similarity from noisy, outlier-ridden data."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from smokeseer.registration import Sim3, pair_by_timestamp, ransac_sim3, register_trajectories, umeyama


def _known_sim3(seed: int) -> Sim3:
    rng = np.random.default_rng(seed)
    rot = Rotation.random(random_state=seed).as_matrix()
    return Sim3(scale=float(rng.uniform(0.3, 3.0)), rotation=rot, translation=rng.normal(0, 5, 3))


def _rot_err_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = (np.trace(a.T @ b) - 1) / 2
    return math.degrees(math.acos(np.clip(c, -1, 1)))


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_umeyama_exact_on_noise_free_points(seed: int) -> None:
    truth = _known_sim3(seed)
    src = np.random.default_rng(seed + 1).normal(size=(20, 3))
    est = umeyama(src, truth.apply(src))
    assert est.scale == pytest.approx(truth.scale, rel=1e-9)
    np.testing.assert_allclose(est.rotation, truth.rotation, atol=1e-9)
    np.testing.assert_allclose(est.translation, truth.translation, atol=1e-8)


def test_umeyama_matches_scipy_rotation_fit() -> None:
    """Independent reference: scipy's Kabsch (align_vectors) on centred, scale-free points."""
    truth = _known_sim3(3)
    rng = np.random.default_rng(4)
    src = rng.normal(size=(50, 3))
    dst = truth.apply(src) + rng.normal(0, 0.01, size=(50, 3))
    est = umeyama(src, dst)
    ref, _ = Rotation.align_vectors(dst - dst.mean(0), src - src.mean(0))
    np.testing.assert_allclose(est.rotation, ref.as_matrix(), atol=1e-9)


def test_ransac_recovers_sim3_with_noise_and_outliers() -> None:
    truth = _known_sim3(11)
    rng = np.random.default_rng(12)
    t = np.linspace(0, 2 * np.pi, 120)
    src = np.stack([3 * np.cos(t), 2 * np.sin(t), 0.5 * np.sin(3 * t)], axis=1)
    dst = truth.apply(src) + rng.normal(0, 0.01 * truth.scale, size=src.shape)
    bad = rng.choice(len(src), size=36, replace=False)  # 30% gross outliers
    dst[bad] += rng.normal(0, 5 * truth.scale, size=(36, 3))
    res = ransac_sim3(src, dst, threshold=0.1 * truth.scale, seed=0)
    assert res.sim3.scale == pytest.approx(truth.scale, rel=0.01)
    assert _rot_err_deg(res.sim3.rotation, truth.rotation) < 0.5
    assert np.linalg.norm(res.sim3.translation - truth.translation) < 0.05 * truth.scale + 0.05
    assert not res.inliers[bad].any() or res.inliers[bad].mean() < 0.1
    # Plain least squares is pulled off by the same outliers: RANSAC is doing the work.
    plain = umeyama(src, dst)
    assert abs(plain.scale - truth.scale) > abs(res.sim3.scale - truth.scale)


def test_trajectory_registration_with_unsynchronised_timestamps() -> None:
    """Two co-located cameras at different rates and a time offset, posed in different frames."""
    truth = _known_sim3(21)
    rng = np.random.default_rng(22)

    def path(tt: np.ndarray) -> np.ndarray:
        return np.stack([4 * np.cos(0.5 * tt), 4 * np.sin(0.5 * tt), 1.0 + 0.3 * np.sin(tt)], axis=1)

    t_rgb = np.arange(0, 10, 1 / 12)
    t_th = np.arange(0.03, 10, 1 / 9)
    rgb = path(t_rgb)
    thermal_in_rgb = path(t_th) + rng.normal(0, 0.005, size=(len(t_th), 3))
    thermal_own = truth.apply(thermal_in_rgb)  # thermal SfM frame = truth(rgb frame)
    thermal_own[::15] += rng.normal(0, 3, size=thermal_own[::15].shape)  # broken poses
    res = register_trajectories(thermal_own, t_th, rgb, t_rgb, seed=0)
    inv_scale = 1.0 / truth.scale
    assert res.sim3.scale == pytest.approx(inv_scale, rel=0.02)
    assert _rot_err_deg(res.sim3.rotation, truth.rotation.T) < 1.0
    mapped = res.sim3.apply(thermal_own[1::15])
    assert np.abs(mapped - thermal_in_rgb[1::15]).max() < 0.1


def test_viewmat_transform_moves_camera_centre_consistently() -> None:
    truth = _known_sim3(5)
    v = np.eye(4)
    v[:3, :3] = Rotation.random(random_state=6).as_matrix()
    v[:3, 3] = [0.3, -1.0, 2.0]
    centre = -v[:3, :3].T @ v[:3, 3]
    w = truth.transform_viewmat(v)
    np.testing.assert_allclose(-w[:3, :3].T @ w[:3, 3], truth.apply(centre[None])[0], atol=1e-9)
    # A world point keeps its camera-frame direction (depth scales by s).
    p = np.array([0.5, 0.2, 3.0])
    pc = v[:3, :3] @ p + v[:3, 3]
    pc2 = w[:3, :3] @ truth.apply(p[None])[0] + w[:3, 3]
    np.testing.assert_allclose(pc2, truth.scale * pc, atol=1e-9)


def test_pair_by_timestamp_respects_max_dt() -> None:
    ia, jb = pair_by_timestamp(np.array([0.0, 1.0, 2.0, 5.0]), np.array([0.1, 1.95, 9.0]), max_dt=0.2)
    assert ia.tolist() == [0, 2]
    assert jb.tolist() == [0, 1]


def test_invalid_input_raises_named_errors() -> None:
    with pytest.raises(ValueError, match="src"):
        umeyama(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="src"):
        umeyama(np.ones((5, 3)), np.ones((5, 3)))
    with pytest.raises(ValueError, match="threshold"):
        ransac_sim3(np.random.rand(5, 3), np.random.rand(5, 3), threshold=0.0)
    with pytest.raises(ValueError, match="NaN"):
        umeyama(np.full((4, 3), np.nan), np.zeros((4, 3)))
