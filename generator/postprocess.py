"""Raw worker renders → dataset files: depth cleanup, smoke masks, area-averaging to the
thermal sensor, and the thermal camera model."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.dataset_format import PASS_FILES, file_path, has_frame
from contracts.imageio import read_exr, read_exr_channel, read_png, write_exr, write_png
from generator.optics.sensor import ThermalSensor, area_average

NO_HIT_DEPTH = 1e9


@dataclass(frozen=True)
class PostContext:
    raw: Path
    out: Path
    requested: dict[str, tuple[str, ...]]
    mask_threshold: float
    sensor: ThermalSensor | None

    def to_sensor_grid(self, image: np.ndarray) -> np.ndarray:
        assert self.sensor is not None
        factor = (image.shape[0] // self.sensor.config.height, image.shape[1] // self.sensor.config.width)
        return area_average(image, factor).astype(np.float32)


def _depth(raw_file: Path) -> np.ndarray:
    channels = read_exr(raw_file)
    key = next((k for k in channels if k.endswith("Depth.Z")), None)
    if key is None:
        raise RuntimeError(f"{raw_file}: worker depth render has no Z channel ({sorted(channels)})")
    depth = channels[key].astype(np.float32)
    depth[~np.isfinite(depth) | (depth >= NO_HIT_DEPTH)] = 0.0
    return depth


def read_alpha(raw_file: Path) -> np.ndarray:
    return np.clip(read_exr_channel(raw_file, "A"), 0.0, 1.0)


def read_radiance(raw_file: Path) -> np.ndarray:
    """A thermal render's radiance: its grey emission, averaged over the RGB channels."""
    channels = read_exr(raw_file)
    rgb = np.stack([channels[c] for c in ("R", "G", "B")], axis=-1)
    return np.clip(rgb.mean(axis=-1), 0.0, None).astype(np.float64)


def _write_alpha(ctx: PostContext, modality: str, stem: str, alpha: np.ndarray) -> None:
    alpha_file, mask_file = PASS_FILES[(modality, "smoke_alpha")]
    write_exr(file_path(ctx.out, alpha_file, stem), {"A": alpha})
    write_png(file_path(ctx.out, mask_file, stem), np.where(alpha > ctx.mask_threshold, 255, 0).astype(np.uint8))


def _wanted(ctx: PostContext, modality: str, name: str) -> bool:
    return name in ctx.requested.get(modality, ())


def finish_rgb_frame(ctx: PostContext, stem: str, split: str) -> None:
    for name in ("smoky", "clean", "shadowed"):
        if _wanted(ctx, "rgb", name) and has_frame("rgb", name, split):
            # Re-encoded pixels only: Cycles writes render times into PNG metadata, which would
            # make identical renders differ byte for byte.
            write_png(file_path(ctx.out, PASS_FILES[("rgb", name)][0], stem),
                      read_png(ctx.raw / "rgb" / name / f"{stem}.png"))
    if _wanted(ctx, "rgb", "depth"):
        write_exr(file_path(ctx.out, PASS_FILES[("rgb", "depth")][0], stem),
                  {"Z": _depth(ctx.raw / "rgb" / "depth" / f"{stem}.exr")})
    if _wanted(ctx, "rgb", "smoke_alpha"):
        _write_alpha(ctx, "rgb", stem, read_alpha(ctx.raw / "rgb" / "smoke_alpha" / f"{stem}.exr"))


def finish_thermal_frame(ctx: PostContext, stem: str, frame_index: int) -> None:
    """Radiance is composed at render resolution, then area-averaged onto sensor pixels."""
    raw = ctx.raw / "thermal"
    alpha_hi = read_alpha(raw / "smoke_alpha" / f"{stem}.exr") if (raw / "smoke_alpha" / f"{stem}.exr").exists() else None
    for name in ("smoky", "clean"):
        if not _wanted(ctx, "thermal", name):
            continue
        radiance_hi = read_radiance(raw / name / f"{stem}.exr")
        radiance_file, counts_file = PASS_FILES[("thermal", name)]
        write_exr(file_path(ctx.out, radiance_file, stem),
                  {"L": ctx.to_sensor_grid(radiance_hi)})
        assert ctx.sensor is not None
        write_png(file_path(ctx.out, counts_file, stem), ctx.sensor.to_counts(radiance_hi, frame_index))
    if _wanted(ctx, "thermal", "depth"):
        write_exr(file_path(ctx.out, PASS_FILES[("thermal", "depth")][0], stem),
                  {"Z": _depth(raw / "depth" / f"{stem}.exr")})
    if _wanted(ctx, "thermal", "smoke_alpha") and alpha_hi is not None:
        _write_alpha(ctx, "thermal", stem, ctx.to_sensor_grid(alpha_hi))


def psnr_u8(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) / 255 - b.astype(np.float64) / 255) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)
