"""``load_scene``: which reader a folder needs, decided by the files each layout must have."""
from __future__ import annotations

from pathlib import Path

from contracts.dataset_format import DATASET_FILE
from contracts.errors import DatasetError
from scenes.capture import CAPTURE_FILE, is_capture, load_capture
from scenes.generated import load_generated
from scenes.official_layouts import detect_official_layout, load_official
from scenes.scene import SceneData
from scenes.splits import hold_out_validation
from scenes.thermal_scale import LINEAR_SCALE, ThermalScaleSpec


def load_scene(path: Path, max_width: int = 0, thermal_scale: ThermalScaleSpec = LINEAR_SCALE,
               validation_every: int = 0, all_ground_truth: bool = False) -> SceneData:
    """Load a generated dataset (has dataset.json), one of the official SmokeSeer layouts
    (transforms_train.json or sparse/0/images.bin), or our capture layout (docs/real-captures.md);
    a folder that is none of them is refused naming what was looked for. Every
    ``validation_every``-th RGB training frame is held out for validation (``scenes.splits``),
    before a generated dataset's ground truth is read for its evaluation (test and validation)
    frames only, as training needs; ``all_ground_truth`` reads it for every frame (conversion and
    analysis tools, never the trainer)."""
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: not a directory")
    if (path / DATASET_FILE).exists():
        return load_generated(path, max_width, thermal_scale, validation_every, all_ground_truth)
    layout = detect_official_layout(path)
    if layout is not None:
        scene = load_official(path, layout, max_width, thermal_scale)
    elif is_capture(path):
        scene = load_capture(path, max_width, thermal_scale)
    else:
        scene = None
    if scene is not None:
        hold_out_validation(scene.rgb.frames, validation_every)
        return scene
    raise DatasetError(
        f"{path}: neither a generated dataset (no {DATASET_FILE}) nor a capture layout (no {CAPTURE_FILE}, "
        "rgb/images/, rgb/sparse/images.txt or transforms_rgb.json naming its image files), nor an official "
        "SmokeSeer layout (no transforms_train.json or sparse/0/images.bin); docs/real-captures.md")
