"""``load_scene``: which reader a folder needs, decided by the files each layout must have."""
from __future__ import annotations

from pathlib import Path

from contracts.dataset_format import DATASET_FILE
from contracts.errors import DatasetError
from scenes.capture import CAPTURE_FILE, is_capture, load_capture
from scenes.generated import load_generated
from scenes.official_layouts import detect_official_layout, load_official
from scenes.scene import SceneData
from scenes.thermal_scale import LINEAR_SCALE, ThermalScaleSpec


def load_scene(path: Path, max_width: int = 0, thermal_scale: ThermalScaleSpec = LINEAR_SCALE) -> SceneData:
    """Load a generated dataset (has dataset.json), one of the official SmokeSeer layouts
    (transforms_train.json or sparse/0/images.bin), or our capture layout (docs/real-captures.md);
    a folder that is none of them is refused naming what was looked for."""
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: not a directory")
    if (path / DATASET_FILE).exists():
        return load_generated(path, max_width, thermal_scale)
    layout = detect_official_layout(path)
    if layout is not None:
        return load_official(path, layout, max_width, thermal_scale)
    if is_capture(path):
        return load_capture(path, max_width, thermal_scale)
    raise DatasetError(
        f"{path}: neither a generated dataset (no {DATASET_FILE}) nor a capture layout (no {CAPTURE_FILE}, "
        "rgb/images/, rgb/sparse/images.txt or transforms_rgb.json naming its image files), nor an official "
        "SmokeSeer layout (no transforms_train.json or sparse/0/images.bin); docs/real-captures.md")
