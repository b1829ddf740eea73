"""Image files: EXR (float32) and PNG (8- and 16-bit), read with errors that name the file, and
written atomically (contracts.atomic) so a resume never trusts a truncated file.

The one reader of image files for the generator, the validator, the scene loaders (``scenes``)
and the harness: a PNG comes back with the channels it stores (alpha included, for the layouts
whose rule composites it) and its integer type, which says the full scale (``image01``).
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from pathlib import Path
from typing import Iterator

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


@contextlib.contextmanager
def _library_output() -> Iterator[list[str]]:
    """Capture what the OpenEXR library prints itself on file descriptors 1 and 2 (it reports
    corrupt chunks there), so a bad file gives one line from us instead of library noise."""
    captured: list[str] = []
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    python_level = io.StringIO()
    with tempfile.TemporaryFile(mode="w+b") as sink, contextlib.redirect_stderr(python_level), \
            contextlib.redirect_stdout(python_level):
        for fd in saved:
            os.dup2(sink.fileno(), fd)
        try:
            yield captured
        finally:
            for fd, original in saved.items():
                os.dup2(original, fd)
                os.close(original)
            sink.seek(0)
            text = sink.read().decode(errors="replace") + python_level.getvalue()
            captured.extend(line for line in text.splitlines() if line.strip())


def read_exr(path: Path | str) -> dict[str, np.ndarray]:
    """All channels of every part by full name (Blender's multilayer names kept, e.g. 'ViewLayer.Depth.Z')."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    with _library_output() as library_messages:
        try:
            with OpenEXR.File(str(path), separate_channels=True) as exr:
                channels = {name: np.asarray(ch.pixels) for part in exr.parts for name, ch in part.channels.items()}
        except Exception as exc:  # OpenEXR raises RuntimeError/OSError variants for bad files
            channels, library_messages[:0] = {}, [str(exc)]
    if not channels or any(a.dtype == object or a.ndim != 2 for a in channels.values()):
        detail = library_messages[0].replace(f"{path}: ", "") if library_messages else "no pixel data"
        raise DatasetError(f"{path}: not a readable EXR image, truncated or corrupt ({detail})")
    return channels


def read_exr_channel(path: Path | str, channel: str) -> np.ndarray:
    """One channel as float32 (half-float files widen exactly)."""
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


def png_bit_depth(path: Path) -> int:
    """Bits per sample from the PNG header (IHDR byte 24)."""
    with path.open("rb") as fh:
        head = fh.read(25)
    if len(head) < 25 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        raise DatasetError(f"{path}: not a PNG file (no IHDR header)")
    return int(head[24])


def read_png(path: Path | str) -> np.ndarray:
    """A PNG (or another image Pillow reads) with its stored integer type and channels: uint16 H×W
    for 16-bit grey; uint8 H×W (L), H×W×2 (LA), H×W×3 (RGB) or H×W×4 (RGBA); any other mode
    (palette, bilevel) converted to RGB.

    Pillow reads 16-bit colour PNGs as 8-bit RGB, so the dtype, not the values, says which full
    scale applies (``image01``); a dark 16-bit frame is never mistaken for an 8-bit one.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    try:
        with Image.open(path) as img:
            img.load()
            if img.mode in ("I;16", "I;16B", "I;16L", "I"):
                if path.suffix.lower() == ".png" and png_bit_depth(path) != 16:
                    raise DatasetError(f"{path}: {png_bit_depth(path)}-bit integer PNG; expected 8- or 16-bit")
                return np.asarray(img).astype(np.uint16)
            if img.mode not in ("L", "LA", "RGB", "RGBA"):
                img = img.convert("RGB")
            return np.asarray(img).astype(np.uint8)
    except DatasetError:
        raise
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a readable PNG image ({exc})") from None


def image01(arr: np.ndarray) -> np.ndarray:
    """Integer image to float64 in [0, 1] by its type's full scale (8- or 16-bit)."""
    if arr.dtype == np.uint16:
        return arr.astype(np.float64) / 65535.0
    if arr.dtype == np.uint8:
        return arr.astype(np.float64) / 255.0
    raise TypeError(f"image01: expected uint8 or uint16, got {arr.dtype}")
