"""What every scene reader returns: frames with their cameras, images per modality, and the scene."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from scenes.thermal_scale import ThermalScale


@dataclass
class Frame:
    """One image's camera at the working resolution."""

    file_stem: str
    viewmat: np.ndarray
    K: np.ndarray
    width: int
    height: int
    timestamp_s: float
    time: float
    split: str


@dataclass
class ModalityData:
    """All frames of one camera; ``images`` is the training input (smoky), others optional."""

    name: str
    frames: list[Frame]
    images: np.ndarray
    clean: np.ndarray | None = None
    shadowed: np.ndarray | None = None
    """RGB scoring only: the frames under the smoke's shadow with no smoke in view (``rgb.shadowed``)."""
    masks: np.ndarray | None = None
    depth: np.ndarray | None = None
    scale: ThermalScale | None = None
    """Thermal only: the dataset's curve from raw values to ``images`` (scenes.thermal_scale)."""
    inverse_depth: np.ndarray | None = None
    """A depth prior the layout carries (the official ``images_depth``): inverse depth in the
    model's units, 0 where there is none. Truth for scoring only if the layout says so."""

    def indices(self, split: str) -> list[int]:
        return [i for i, f in enumerate(self.frames) if f.split == split]

    def cameras(self, split: str) -> tuple[np.ndarray, np.ndarray]:
        """The split's world-to-camera matrices (N, 4, 4) and intrinsics (N, 3, 3), in ``indices`` order."""
        frames = [self.frames[i] for i in self.indices(split)]
        return np.stack([f.viewmat for f in frames]), np.stack([f.K for f in frames])

    @property
    def channels(self) -> int:
        return int(self.images.shape[-1])


@dataclass
class SceneData:
    """A scene ready for training: RGB always, thermal when the capture has it."""

    name: str
    path: Path
    rgb: ModalityData
    thermal: ModalityData | None
    smoke_present: bool
    smoke_static: bool
    mask_threshold: float
    synthetic: bool
    init_points: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    """What the loader assumed or left out (no masks, no timestamps, ...): logged and written
    to metrics.json so a substitution is never silent."""
    poses: dict[str, Any] | None = None
    """Where the poses were estimated, per modality (SfM counts and timings, the rig's
    extrinsic): None when the layout brought them. Written to metrics.json."""
    score_depth_scale: float = 1.0
    """Scoring only: ground-truth depth units per pose unit. 1 with the dataset's poses; with
    poses from SfM, the scale that takes the SfM camera centres onto the dataset's."""


def set_times(rgb: ModalityData, thermal: ModalityData | None, duration: Any) -> None:
    """Normalised time from timestamps: t = (timestamp − first RGB timestamp) / duration."""
    frames = rgb.frames + (thermal.frames if thermal else [])
    t0 = min(f.timestamp_s for f in rgb.frames)
    if isinstance(duration, (int, float)) and duration > 0:
        span = float(duration)
    else:
        span = max(f.timestamp_s for f in frames) - t0
    span = span if span > 0 else 1.0
    for f in frames:
        f.time = float(np.clip((f.timestamp_s - t0) / span, 0.0, 1.0))
