"""Single-image dehazers for the ImgDehaze + Deformable 3DGS baseline.

The paper's baseline uses ConvIR, whose weights are not available offline, so the
default is the dark channel prior (He et al., CVPR 2009 / TPAMI 2011) with
guided-filter refinement of the transmission (He et al., ECCV 2010). Other
dehazers (a learned one with local weights) plug in through the registry.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Protocol, runtime_checkable

import numpy as np
from PIL import Image
from scipy import ndimage

from contracts.atomic import write_json


@runtime_checkable
class Dehazer(Protocol):
    """Maps one H×W×3 sRGB image in [0, 1] to its dehazed estimate, same shape and range."""

    name: str

    def __call__(self, rgb: np.ndarray) -> np.ndarray: ...


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def dark_channel(img: np.ndarray, patch: int) -> np.ndarray:
    """Minimum over colour channels, then over a patch×patch window."""
    return ndimage.minimum_filter(img.min(axis=2), size=patch, mode="nearest")


def estimate_airlight(img: np.ndarray, dark: np.ndarray, top_fraction: float = 0.001) -> np.ndarray:
    """Among the brightest `top_fraction` of dark-channel pixels, the most intense input pixel."""
    n = max(1, int(round(dark.size * top_fraction)))
    idx = np.argpartition(dark.ravel(), -n)[-n:]
    cand = img.reshape(-1, 3)[idx]
    return cand[np.argmax(cand.sum(axis=1))]


def guided_filter(guide: np.ndarray, src: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """Grey-guide guided filter: an edge-preserving local linear fit of src to guide."""
    size = 2 * radius + 1

    def box(x: np.ndarray) -> np.ndarray:
        return ndimage.uniform_filter(x, size=size, mode="reflect")

    mean_i, mean_p = box(guide), box(src)
    var_i = box(guide * guide) - mean_i**2
    cov_ip = box(guide * src) - mean_i * mean_p
    a = cov_ip / (var_i + eps)
    b = mean_p - a * mean_i
    return box(a) * guide + box(b)


@dataclass(frozen=True)
class DarkChannelPrior:
    """He et al.'s dehazer. Sizes default to He's 15 px patch and 60 px guided radius
    for a 600 px image, scaled to the input so small synthetic frames are not over-smoothed."""

    omega: float = 0.95
    t0: float = 0.1
    patch: int | None = None
    guided_radius: int | None = None
    guided_eps: float = 1e-3
    linearize: bool = True
    name: str = "dcp"

    def __post_init__(self) -> None:
        if not 0.0 < self.omega <= 1.0:
            raise ValueError(f"omega: must be in (0, 1], got {self.omega}")
        if not 0.0 < self.t0 < 1.0:
            raise ValueError(f"t0: must be in (0, 1), got {self.t0}")
        if self.patch is not None and self.patch < 1:
            raise ValueError(f"patch: must be >= 1, got {self.patch}")
        if self.guided_eps <= 0:
            raise ValueError(f"guided_eps: must be > 0, got {self.guided_eps}")

    def sizes(self, h: int, w: int) -> tuple[int, int]:
        patch = self.patch or max(3, int(round(min(h, w) * 15 / 600)) | 1)
        radius = self.guided_radius or max(2, 4 * patch)
        return patch, radius

    def dehaze_linear(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Dehaze a linear-radiance image; returns (J, refined transmission, airlight A)."""
        patch, radius = self.sizes(*img.shape[:2])
        air = np.maximum(estimate_airlight(img, dark_channel(img, patch)), 1e-3)
        t_raw = 1.0 - self.omega * dark_channel(img / air, patch)
        gray = img @ np.array([0.2126, 0.7152, 0.0722])
        t = np.clip(guided_filter(gray, t_raw, radius, self.guided_eps), self.t0, 1.0)
        j = (img - air) / t[..., None] + air
        return np.clip(j, 0.0, 1.0), t, air

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        if rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"rgb: expected H×W×3, got shape {rgb.shape}")
        x = np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0)
        if self.linearize:
            return linear_to_srgb(self.dehaze_linear(srgb_to_linear(x))[0])
        return self.dehaze_linear(x)[0]


_REGISTRY: dict[str, Callable[..., Dehazer]] = {"dcp": DarkChannelPrior}


def register_dehazer(name: str, factory: Callable[..., Dehazer]) -> None:
    """Make a dehazer selectable by name (e.g. a learned model loading local weights)."""
    _REGISTRY[name] = factory


def available_dehazers() -> list[str]:
    return sorted(_REGISTRY)


def get_dehazer(name: str, **kwargs: object) -> Dehazer:
    if name not in _REGISTRY:
        raise ValueError(f"dehazer: unknown {name!r}, available: {available_dehazers()}")
    return _REGISTRY[name](**kwargs)


def _link_or_copy(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def dehaze_dataset(src: Path, dst: Path, dehazer: Dehazer) -> Path:
    """Copy a dataset (docs/dataset-format.md) with every `rgb/smoky` frame dehazed.

    Unchanged files are hard-linked (copied across filesystems); the files we rewrite
    are fresh files, so the source dataset is never modified through a shared inode.
    `dataset.json` gains a `dehazed_by` entry naming the dehazer and its settings.
    """
    src, dst = Path(src), Path(dst)
    meta_path = src / "dataset.json"
    if not meta_path.is_file():
        raise ValueError(f"src: {src} has no dataset.json")
    smoky_dir = src / "rgb" / "smoky"
    if not smoky_dir.is_dir():
        raise ValueError(f"src: {src} has no rgb/smoky frames to dehaze")
    if dst.exists():
        shutil.rmtree(dst)
    tmp = dst.with_name(dst.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    for root, _dirs, files in os.walk(src):
        rel = Path(root).relative_to(src)
        (tmp / rel).mkdir(parents=True, exist_ok=True)
        for f in files:
            if rel == Path("rgb/smoky") or (rel == Path(".") and f == "dataset.json"):
                continue
            _link_or_copy(Path(root) / f, tmp / rel / f)
    for frame in sorted(smoky_dir.glob("*.png")):
        rgb = np.asarray(Image.open(frame).convert("RGB"), dtype=np.float64) / 255.0
        out = dehazer(rgb)
        Image.fromarray(np.round(np.clip(out, 0, 1) * 255).astype(np.uint8)).save(tmp / "rgb/smoky" / frame.name)
    meta = json.loads(meta_path.read_text())
    settings = asdict(dehazer) if hasattr(dehazer, "__dataclass_fields__") else {}
    meta["dehazed_by"] = {"name": dehazer.name, "settings": settings, "source": str(src.resolve())}
    write_json(tmp / "dataset.json", meta)
    tmp.rename(dst)
    return dst
