"""Image files of the dataset: EXR (float32) and PNG (8- and 16-bit), read with errors that name
the file, and written atomically (contracts.atomic) so a resume never trusts a truncated file.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image

from contracts.atomic import atomic_path
from contracts.errors import DatasetError


def write_exr(path: Path, channels: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {name: np.ascontiguousarray(arr, dtype=np.float32) for name, arr in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp:
        OpenEXR.File(header, data).write(str(tmp))


def read_exr(path: Path) -> dict[str, np.ndarray]:
    """All channels of every part by full name (Blender's multilayer names kept, e.g. 'ViewLayer.Depth.Z')."""
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            return {name: np.asarray(ch.pixels) for part in exr.parts for name, ch in part.channels.items()}
    except Exception as exc:  # OpenEXR raises RuntimeError/OSError variants for bad files
        raise DatasetError(f"{path}: not a readable EXR image ({exc})") from None


def read_exr_channel(path: Path, channel: str) -> np.ndarray:
    channels = read_exr(path)
    if channel not in channels:
        raise DatasetError(f"{path}: EXR has no channel {channel!r} (has {', '.join(sorted(channels))})")
    return channels[channel].astype(np.float32)


def write_png(path: Path, image: np.ndarray) -> None:
    """uint8 H×W or H×W×3, or uint16 H×W."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not (image.dtype == np.uint16 and image.ndim == 2) and image.dtype != np.uint8:
        raise ValueError(f"cannot write {image.dtype} {image.shape} as PNG")
    pil = Image.fromarray(np.ascontiguousarray(image))
    with atomic_path(path) as tmp:
        pil.save(tmp, format="PNG", compress_level=6)


def read_png(path: Path) -> np.ndarray:
    try:
        with Image.open(path) as img:
            img.load()
            if img.mode in ("I;16", "I;16B", "I;16L"):
                return np.asarray(img, dtype=np.uint16)
            if img.mode not in ("L", "RGB"):
                img = img.convert("RGB")
            return np.asarray(img)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a readable PNG image ({exc})") from None
