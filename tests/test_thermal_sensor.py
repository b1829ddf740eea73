"""Thermal camera model: exact inversion, noise statistics, seeding, resampling and blur."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from generator.optics.planck import band_radiance, band_radiance_derivative
from generator.optics.sensor import ThermalSensor, ThermalSensorConfig, area_average, gaussian_blur

CLEAN = dict(netd_k=0.0, blur_sigma_px=0.0, fpn_gain_std=0.0, fpn_offset_k=0.0, fpn_row_k=0.0,
             fpn_col_k=0.0)


def _sensor(seed: int = 0, **overrides: object) -> ThermalSensor:
    params: dict[str, object] = dict(width=64, height=48)
    params.update(overrides)
    return ThermalSensor(ThermalSensorConfig(**params), seed=seed)  # type: ignore[arg-type]


@pytest.mark.parametrize("bits", [14, 16])
def test_noise_free_sensor_inverts_up_to_quantisation(bits: int) -> None:
    sensor = _sensor(bits=bits, **CLEAN)
    rng = np.random.default_rng(1)
    temps = rng.uniform(sensor.config.t_min_k, sensor.config.t_max_k, (48, 64))
    lum = band_radiance(temps)
    counts = sensor.to_counts(lum)
    assert counts.dtype == np.uint16
    assert np.max(np.abs(sensor.to_radiance(counts) - lum)) <= 0.5 * sensor.gain * (1 + 1e-9)
    # The quantiser is exactly invertible on its own grid.
    grid = rng.integers(0, sensor.max_count + 1, (48, 64)).astype(np.uint16)
    np.testing.assert_array_equal(sensor.to_counts(sensor.to_radiance(grid)), grid)
    # Temperature error bounded by half a count through the local slope.
    half_count_k = 0.5 * sensor.gain / band_radiance_derivative(temps)
    assert np.all(np.abs(sensor.to_temperature(counts) - temps) <= half_count_k * 1.001)


def test_gain_and_offset_come_from_the_configured_span() -> None:
    sensor = _sensor(t_min_k=250.0, t_max_k=400.0, bits=14, **CLEAN)
    assert sensor.offset == pytest.approx(float(band_radiance(250.0)), rel=1e-15)
    assert sensor.gain == pytest.approx(float(band_radiance(400.0) - band_radiance(250.0)) / 16383)
    hot_cold = sensor.to_counts(np.array([[1e4] * 64] * 24 + [[0.0] * 64] * 24))
    assert hot_cold[0, 0] == 16383 and hot_cold[-1, 0] == 0
    # Independent of the image: a dim frame and a bright frame share the scale.
    assert sensor.to_counts(np.full((48, 64), float(band_radiance(300.0))))[0, 0] == round(
        (float(band_radiance(300.0)) - sensor.offset) / sensor.gain
    )


@pytest.mark.parametrize("netd", [0.04, 0.1])
def test_flat_field_noise_matches_netd(netd: float) -> None:
    sensor = ThermalSensor(ThermalSensorConfig(**{**CLEAN, "netd_k": netd}), seed=3)
    flat = np.full((512, 640), float(band_radiance(sensor.config.reference_temperature_k)))
    temps = sensor.to_temperature(sensor.to_counts(flat, frame_index=5))
    assert temps.std() == pytest.approx(netd, rel=0.1)
    assert temps.mean() == pytest.approx(sensor.config.reference_temperature_k, abs=netd / 10)


def test_fixed_pattern_statistics() -> None:
    cfg = {**CLEAN, "fpn_offset_k": 0.05, "fpn_row_k": 0.03, "fpn_col_k": 0.02}
    sensor = ThermalSensor(ThermalSensorConfig(**cfg), seed=11)
    slope = sensor.radiance_per_kelvin
    offsets_k = sensor.fpn_offset / slope
    assert offsets_k.std() == pytest.approx(np.sqrt(0.05**2 + 0.03**2 + 0.02**2), rel=0.1)
    assert offsets_k.mean(axis=1).std() == pytest.approx(0.03, rel=0.15)  # row term
    assert offsets_k.mean(axis=0).std() == pytest.approx(0.02, rel=0.15)  # column term
    gain = ThermalSensor(ThermalSensorConfig(**{**CLEAN, "fpn_gain_std": 0.01}), seed=11).fpn_gain
    assert gain.std() == pytest.approx(0.01, rel=0.05) and gain.mean() == pytest.approx(1, abs=1e-3)


def test_gain_fpn_vanishes_at_the_calibration_temperature() -> None:
    sensor = _sensor(**{**CLEAN, "fpn_gain_std": 0.02})
    at_ref = np.full((48, 64), sensor.reference_radiance)
    np.testing.assert_allclose(sensor.sensor_radiance(at_ref), at_ref, rtol=1e-14)
    hot = np.full((48, 64), float(band_radiance(380.0)))
    assert np.std(sensor.sensor_radiance(hot)) > 0


def test_seeds_reproduce_and_separate() -> None:
    scene = band_radiance(np.random.default_rng(0).uniform(280, 320, (96, 128)))
    a, b = _sensor(seed=7), _sensor(seed=7)
    assert a.to_counts(scene, 3).tobytes() == b.to_counts(scene, 3).tobytes()
    assert a.to_counts(scene, 3).tobytes() != a.to_counts(scene, 4).tobytes()
    assert a.to_counts(scene, 3).tobytes() != _sensor(seed=8).to_counts(scene, 3).tobytes()
    # Same FPN in every frame: with temporal noise off, frames are identical.
    quiet = _sensor(seed=7, netd_k=0.0)
    np.testing.assert_array_equal(quiet.to_counts(scene, 0), quiet.to_counts(scene, 9))
    np.testing.assert_array_equal(quiet.fpn_offset, a.fpn_offset)
    assert not np.array_equal(_sensor(seed=8).fpn_offset, a.fpn_offset)


def test_area_average() -> None:
    small = np.random.default_rng(2).uniform(0, 1, (6, 8))
    np.testing.assert_allclose(area_average(np.kron(small, np.ones((3, 3))), 3), small, rtol=1e-14)
    np.testing.assert_allclose(area_average(np.kron(small, np.ones((2, 4))), (2, 4)), small, rtol=1e-14)
    img = np.arange(16.0).reshape(4, 4)
    assert area_average(img, 2)[0, 0] == pytest.approx(np.mean([0, 1, 4, 5]))
    with pytest.raises(ValueError, match="divisible"):
        area_average(np.zeros((5, 4)), 2)
    with pytest.raises(ValueError, match="integer multiple"):
        _sensor().to_counts(np.zeros((50, 64)))
    sensor = _sensor(**CLEAN)
    coarse = band_radiance(np.full((48, 64), 300.0))
    np.testing.assert_array_equal(sensor.to_counts(np.kron(coarse, np.ones((2, 2)))), sensor.to_counts(coarse))


@pytest.mark.parametrize("sigma", [0.5, 1.3, 3.0])
def test_gaussian_blur_matches_scipy(sigma: float) -> None:
    img = np.random.default_rng(4).uniform(0, 100, (20, 31))
    ref = gaussian_filter(img, sigma, mode="reflect", truncate=4.0)
    np.testing.assert_allclose(gaussian_blur(img, sigma), ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(gaussian_blur(img, 0.0), img)
    np.testing.assert_allclose(gaussian_blur(np.full((9, 9), 5.0), sigma), 5.0, rtol=1e-14)


def test_describe_is_json_and_consistent() -> None:
    sensor = _sensor(seed=5)
    desc = json.loads(json.dumps(sensor.describe()))
    assert desc["bits"] == 14 and desc["seed"] == 5
    assert desc["gain"] == sensor.gain and desc["offset"] == sensor.offset
    assert desc["noise_equivalent_radiance"] == pytest.approx(0.04 * 0.84, rel=0.02)


def test_invalid_inputs() -> None:
    for bad in (dict(bits=12), dict(t_min_k=400.0, t_max_k=300.0), dict(netd_k=-0.1),
                dict(width=0), dict(blur_sigma_px=np.nan), dict(band_m=(14e-6, 8e-6))):
        with pytest.raises(ValueError):
            ThermalSensorConfig(**bad)  # type: ignore[arg-type]
    sensor = _sensor()
    with pytest.raises(ValueError, match="radiance_image"):
        sensor.to_counts(np.full((48, 64), np.nan))
    with pytest.raises(ValueError, match="radiance_image"):
        sensor.to_counts(np.full((48, 64), -1.0))
    with pytest.raises(ValueError, match="counts"):
        sensor.to_radiance(np.array([-1, 5]))
    with pytest.raises(ValueError, match="counts"):
        sensor.to_radiance(np.array([2**14]))
    with pytest.raises(ValueError, match="counts"):
        sensor.to_radiance(np.array([1.5]))
    with pytest.raises(ValueError, match="frame_index"):
        sensor.to_counts(np.zeros((48, 64)), frame_index=-1)
    with pytest.raises(ValueError, match="seed"):
        ThermalSensor(ThermalSensorConfig(), seed=-2)
