"""Thermal camera model: in-band radiance image -> raw sensor counts, and back.

Pipeline of `ThermalSensor.to_counts` (each step is why thermal images look the way they do):

1. Area-average to the sensor grid: a microbolometer pixel integrates irradiance over its area;
   the renderer supplies an integer multiple of the sensor resolution.
2. Gaussian optics blur, sigma in sensor pixels (0 = off). Applied after the area average
   (cheaper); for continuous images blur and box averaging commute, so the order only matters
   through the sampling of the kernel on the sensor grid.
3. Fixed-pattern noise, from `seed` only (identical in every frame): residual non-uniformity
   after a two-point NUC, so per-pixel gain g acts on the departure from the reference
   (calibration) radiance: L' = L_ref + g·(L − L_ref) + per-pixel offset + row + column terms.
   The offset terms are given in kelvin at the reference temperature.
4. Temporal noise: white Gaussian in radiance with std NETD · dL/dT(T_ref). Detector noise is a
   fixed noise-equivalent *radiance*, so the NETD in kelvin is exact at T_ref and smaller for
   hotter scenes (where dL/dT is larger). Seeded from (seed, frame_index).
5. Quantisation: counts = clip(round((L' − offset) / gain), 0, 2^bits − 1), with
   offset = L_band(t_min) and gain = (L_band(t_max) − offset) / (2^bits − 1), fixed by the
   configured temperature span and not by the image, so every frame shares one scale.

Defaults follow a FLIR Boson 640 (640×512, NETD < 40 mK, 14-bit, high-gain scene range about
−40…+140 °C); the band is the project's 8–14 µm.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from generator.optics.planck import (
    LWIR_BAND_M,
    band_radiance,
    band_radiance_derivative,
    brightness_temperature,
    validate_band,
)

_FPN_STREAM = 0
_TEMPORAL_STREAM = 1


@dataclass(frozen=True)
class ThermalSensorConfig:
    """Parameters of a microbolometer camera (temperatures in K, noise terms in K at T_ref)."""

    width: int = 640
    height: int = 512
    bits: int = 14
    netd_k: float = 0.04
    reference_temperature_k: float = 300.0
    blur_sigma_px: float = 0.5
    fpn_gain_std: float = 0.005
    fpn_offset_k: float = 0.02
    fpn_row_k: float = 0.01
    fpn_col_k: float = 0.01
    t_min_k: float = 233.15
    t_max_k: float = 413.15
    band_m: tuple[float, float] = LWIR_BAND_M

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        if self.bits not in (14, 16):
            raise ValueError(f"bits must be 14 or 16, got {self.bits!r}")
        for name in ("netd_k", "blur_sigma_px", "fpn_gain_std", "fpn_offset_k", "fpn_row_k",
                     "fpn_col_k"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        for name in ("reference_temperature_k", "t_min_k", "t_max_k"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be finite and > 0 K, got {value!r}")
        if not self.t_min_k < self.t_max_k:
            raise ValueError(f"t_min_k must be < t_max_k, got {self.t_min_k!r}, {self.t_max_k!r}")
        validate_band(self.band_m)


def area_average(image: np.ndarray, factor: int | tuple[int, int]) -> np.ndarray:
    """Mean over each factor×factor (or fy×fx) block: what a pixel integrating irradiance sees."""
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D, got shape {img.shape}")
    fy, fx = (factor, factor) if np.isscalar(factor) else factor
    if any(not isinstance(f, (int, np.integer)) or isinstance(f, bool) or f < 1 for f in (fy, fx)):
        raise ValueError(f"factor must be a positive int or a pair of them, got {factor!r}")
    in_h, in_w = img.shape
    if in_h % fy or in_w % fx:
        raise ValueError(f"image shape {img.shape} is not divisible by the factor {factor!r}")
    return img.reshape(in_h // fy, fy, in_w // fx, fx).mean(axis=(1, 3))


def gaussian_blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """Separable Gaussian blur (kernel radius round(4σ), mirrored edges); sigma 0 is a copy."""
    img = np.asarray(image, dtype=np.float64)
    if not np.isfinite(sigma_px) or sigma_px < 0:
        raise ValueError(f"sigma_px must be finite and >= 0, got {sigma_px!r}")
    if sigma_px == 0:
        return img.copy()
    radius = int(4.0 * sigma_px + 0.5)
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (offsets / sigma_px) ** 2)
    kernel /= kernel.sum()
    out = img
    for axis in (0, 1):
        n = out.shape[axis]
        # Symmetric reflection, repeated so that kernels wider than the image stay valid.
        index = np.arange(-radius, n + radius)
        period = 2 * n
        index = np.mod(index, period)
        index = np.where(index >= n, period - 1 - index, index)
        padded = np.take(out, index, axis=axis)
        acc = np.zeros_like(out)
        for j, weight in enumerate(kernel):
            acc += weight * np.take(padded, np.arange(j, j + n), axis=axis)
        out = acc
    return out


@dataclass(frozen=True, eq=False)
class ThermalSensor:
    """A configured camera instance: its fixed-pattern noise is drawn once from `seed`."""

    config: ThermalSensorConfig = field(default_factory=ThermalSensorConfig)
    seed: int = 0
    fpn_gain: np.ndarray = field(init=False, repr=False)
    fpn_offset: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative int, got {self.seed!r}")
        cfg = self.config
        rng = np.random.default_rng(np.random.SeedSequence([int(self.seed), _FPN_STREAM]))
        shape = (cfg.height, cfg.width)
        slope = self.radiance_per_kelvin
        gain = 1.0 + cfg.fpn_gain_std * rng.standard_normal(shape)
        offset = cfg.fpn_offset_k * slope * rng.standard_normal(shape)
        offset += cfg.fpn_row_k * slope * rng.standard_normal((cfg.height, 1))
        offset += cfg.fpn_col_k * slope * rng.standard_normal((1, cfg.width))
        gain.setflags(write=False)
        offset.setflags(write=False)
        object.__setattr__(self, "fpn_gain", gain)
        object.__setattr__(self, "fpn_offset", offset)

    @property
    def max_count(self) -> int:
        return 2**self.config.bits - 1

    @property
    def offset(self) -> float:
        """Radiance at count 0 (W·m⁻²·sr⁻¹): L_band(t_min)."""
        return float(band_radiance(self.config.t_min_k, self.config.band_m))

    @property
    def gain(self) -> float:
        """Radiance per count: the t_min..t_max radiance span over 2^bits − 1 counts."""
        top = float(band_radiance(self.config.t_max_k, self.config.band_m))
        return (top - self.offset) / self.max_count

    @property
    def reference_radiance(self) -> float:
        return float(band_radiance(self.config.reference_temperature_k, self.config.band_m))

    @property
    def radiance_per_kelvin(self) -> float:
        """dL_band/dT at the reference temperature, used to express kelvin noise in radiance."""
        cfg = self.config
        return float(band_radiance_derivative(cfg.reference_temperature_k, cfg.band_m))

    @property
    def noise_equivalent_radiance(self) -> float:
        """Temporal noise std in W·m⁻²·sr⁻¹: NETD × dL/dT(T_ref)."""
        return self.config.netd_k * self.radiance_per_kelvin

    def sensor_radiance(self, radiance_image: np.ndarray, frame_index: int = 0) -> np.ndarray:
        """Radiance after averaging, blur, fixed-pattern and temporal noise, before quantising."""
        if not isinstance(frame_index, (int, np.integer)) or isinstance(frame_index, bool) or frame_index < 0:
            raise ValueError(f"frame_index must be a non-negative int, got {frame_index!r}")
        img = np.asarray(radiance_image, dtype=np.float64)
        if not np.all(np.isfinite(img)) or np.any(img < 0):
            raise ValueError("radiance_image must be finite and >= 0")
        cfg = self.config
        if img.ndim != 2 or img.shape[0] % cfg.height or img.shape[1] % cfg.width:
            raise ValueError(
                f"radiance_image shape {img.shape} is not an integer multiple of the sensor "
                f"size ({cfg.height}, {cfg.width})"
            )
        factor = (img.shape[0] // cfg.height, img.shape[1] // cfg.width)
        lum = gaussian_blur(area_average(img, factor), cfg.blur_sigma_px)
        ref = self.reference_radiance
        lum = ref + self.fpn_gain * (lum - ref) + self.fpn_offset
        if cfg.netd_k > 0:
            seq = np.random.SeedSequence([int(self.seed), _TEMPORAL_STREAM, int(frame_index)])
            noise = np.random.default_rng(seq).standard_normal(lum.shape)
            lum = lum + self.noise_equivalent_radiance * noise
        return lum

    def to_counts(self, radiance_image: np.ndarray, frame_index: int = 0) -> np.ndarray:
        """Raw uint16 counts of one frame (see the module docstring for the pipeline)."""
        lum = self.sensor_radiance(radiance_image, frame_index)
        counts = np.rint((lum - self.offset) / self.gain)
        return np.clip(counts, 0, self.max_count).astype(np.uint16)

    def _validate_counts(self, counts: np.ndarray) -> np.ndarray:
        c = np.asarray(counts)
        if not np.issubdtype(c.dtype, np.integer):
            raise ValueError(f"counts must have an integer dtype, got {c.dtype}")
        if c.size and (c.min() < 0 or c.max() > self.max_count):
            raise ValueError(f"counts must lie in [0, {self.max_count}] for {self.config.bits} bits")
        return c

    def to_radiance(self, counts: np.ndarray) -> np.ndarray:
        """Nominal inverse of the quantiser: offset + gain·counts (float64, W·m⁻²·sr⁻¹)."""
        c = self._validate_counts(counts)
        return self.offset + self.gain * c.astype(np.float64)

    def to_temperature(self, counts: np.ndarray) -> np.ndarray:
        """Brightness temperature (K) of each count, solved once per distinct count value."""
        c = self._validate_counts(counts)
        values, inverse = np.unique(c, return_inverse=True)
        temps = brightness_temperature(self.to_radiance(values), self.config.band_m)
        return temps[inverse].reshape(c.shape)

    def describe(self) -> dict[str, object]:
        """JSON-able description for dataset.json["thermal_sensor"]."""
        cfg = self.config
        return {
            "model": "microbolometer: area average, Gaussian blur, FPN, temporal noise, quantiser",
            "width": int(cfg.width),
            "height": int(cfg.height),
            "bits": int(cfg.bits),
            "gain": self.gain,
            "offset": self.offset,
            "counts_formula": "counts = clip(round((L - offset) / gain), 0, 2^bits - 1)",
            "radiance_units": "W m^-2 sr^-1 (in-band)",
            "band_um": [cfg.band_m[0] * 1e6, cfg.band_m[1] * 1e6],
            "t_min_k": float(cfg.t_min_k),
            "t_max_k": float(cfg.t_max_k),
            "netd_k": float(cfg.netd_k),
            "reference_temperature_k": float(cfg.reference_temperature_k),
            "noise_equivalent_radiance": self.noise_equivalent_radiance,
            "blur_sigma_px": float(cfg.blur_sigma_px),
            "fpn_gain_std": float(cfg.fpn_gain_std),
            "fpn_offset_k": float(cfg.fpn_offset_k),
            "fpn_row_k": float(cfg.fpn_row_k),
            "fpn_col_k": float(cfg.fpn_col_k),
            "seed": int(self.seed),
        }
