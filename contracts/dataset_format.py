"""The dataset format of docs/dataset-format.md, as code: file layout and a validator."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from contracts.errors import DatasetError
from contracts.imageio import read_exr_channel, read_png

FORMAT = "smokeseer-synth-dataset"
FORMAT_VERSION = 1
DATASET_FILE = "dataset.json"
"""The file that makes a folder a generated dataset: scene-level metadata."""
SPEC_FILE = "scene.yaml"
"""The fully resolved scene spec that produced the dataset."""


@dataclass(frozen=True)
class PassFile:
    folder: str
    ext: str
    dtype: type
    channels: int  # 3 = H×W×3, 1 = H×W
    exr_channel: str | None = None


# (modality, pass) -> the files that pass puts in the dataset.
PASS_FILES: dict[tuple[str, str], tuple[PassFile, ...]] = {
    ("rgb", "smoky"): (PassFile("rgb/smoky", "png", np.uint8, 3),),
    ("rgb", "clean"): (PassFile("rgb/clean", "png", np.uint8, 3),),
    ("rgb", "shadowed"): (PassFile("rgb/shadowed", "png", np.uint8, 3),),
    ("rgb", "depth"): (PassFile("rgb/depth", "exr", np.float32, 1, "Z"),),
    ("rgb", "smoke_alpha"): (PassFile("rgb/smoke_alpha", "exr", np.float32, 1, "A"),
                             PassFile("rgb/smoke_mask", "png", np.uint8, 1)),
    ("thermal", "smoky"): (PassFile("thermal/smoky_radiance", "exr", np.float32, 1, "L"),
                           PassFile("thermal/smoky", "png", np.uint16, 1)),
    ("thermal", "clean"): (PassFile("thermal/clean_radiance", "exr", np.float32, 1, "L"),
                           PassFile("thermal/clean", "png", np.uint16, 1)),
    ("thermal", "depth"): (PassFile("thermal/depth", "exr", np.float32, 1, "Z"),),
    ("thermal", "smoke_alpha"): (PassFile("thermal/smoke_alpha", "exr", np.float32, 1, "A"),
                                 PassFile("thermal/smoke_mask", "png", np.uint8, 1)),
}

MODALITY_PASSES: dict[str, tuple[str, ...]] = {
    modality: tuple(name for m, name in PASS_FILES if m == modality) for modality in ("rgb", "thermal")}
"""The passes each camera has. `shadowed` is RGB only: the thermal render has no lights, so the
smoke casts no shadow there."""

SMOKE_ONLY_PASSES = ("shadowed", "smoke_alpha")
"""The passes a scene without smoke does not have: no smoke opacity, and its shadowed frames would
be its clean ones."""

TEST_VIEW_PASSES: frozenset[tuple[str, str]] = frozenset({("rgb", "shadowed")})
"""The passes rendered for the RGB test views alone. Only scoring reads `shadowed`, and scoring
reads test views, so its other frames would cost render time (a third of a drawn scene's) and be
read by nothing. A dataset made before the rule may hold them for every frame: only the test
views' files are required."""


def has_frame(modality: str, name: str, split: str) -> bool:
    """Whether pass ``modality.name`` puts a file in the dataset for a frame of ``split``."""
    return split == "test" or (modality, name) not in TEST_VIEW_PASSES


GROUND_TRUTH_FOLDERS: frozenset[str] = frozenset(
    pf.folder for (_, name), files in PASS_FILES.items() if name in ("clean", "shadowed", "depth", "smoke_alpha")
    for pf in files if pf.folder.rsplit("/", 1)[1] != "smoke_mask")
"""The folders a real capture has no counterpart of: for scoring only. The smoke masks stay out:
they are the declared oracle Stage 1."""


def file_path(root: Path, pf: PassFile, stem: str) -> Path:
    return root / pf.folder / f"{stem}.{pf.ext}"


def pass_file(modality: str, name: str, ext: str) -> PassFile:
    """The file of pass ``modality.name`` with extension ``ext`` (a pass may write an EXR and a PNG)."""
    matches = [pf for pf in PASS_FILES[(modality, name)] if pf.ext == ext]
    if len(matches) != 1:
        raise KeyError(f"pass {modality}.{name} has no single .{ext} file")
    return matches[0]


def transforms_name(modality: str) -> str:
    return f"transforms_{modality}.json"


def load_json(path: Path) -> dict[str, Any]:
    """A JSON object from ``path``; DatasetError names the file when it is missing or malformed."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: malformed JSON at line {exc.lineno}: {exc.msg}") from None
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: must hold a JSON object")
    return data


def need_field(data: dict[str, Any], key: str, path: Path, kind: type | tuple[type, ...]) -> Any:
    """``data[key]``, which must exist and be of ``kind`` (bools are not numbers)."""
    if key not in data:
        raise DatasetError(f"{path}: field {key!r} is missing")
    if not isinstance(data[key], kind) or isinstance(data[key], bool) and kind is not bool:
        raise DatasetError(f"{path}: field {key!r} has the wrong type ({type(data[key]).__name__})")
    return data[key]


def check_pose(matrix: Any, where: str) -> np.ndarray:
    """A 4×4 rigid c2w: finite, orthonormal rotation with det +1, last row 0 0 0 1. ``where``
    names the file and the frame (``PATH: frames[3]``); the message adds ``.transform_matrix``."""
    field = f"{where}.transform_matrix"
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{field} is missing or not numeric") from None
    if m.shape != (4, 4):
        raise DatasetError(f"{field} must be 4x4, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise DatasetError(f"{field} holds NaN or Inf")
    r = m[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-4) or abs(np.linalg.det(r) - 1) > 1e-4:
        raise DatasetError(f"{field}: rotation is not orthonormal with det +1")
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise DatasetError(f"{field}: last row must be 0 0 0 1")
    return m


def check_camera(data: dict[str, Any], path: Path) -> None:
    """Pinhole intrinsics of a transforms file: positive integer ``w``, ``h``; finite ``cx``, ``cy``
    and positive ``fl_x``, ``fl_y`` in pixels."""
    for key in ("w", "h"):
        if need_field(data, key, path, int) <= 0:
            raise DatasetError(f"{path}: field {key!r} must be positive")
    for key in ("fl_x", "fl_y", "cx", "cy"):
        value = need_field(data, key, path, (int, float))
        if not math.isfinite(value) or (key.startswith("fl") and value <= 0):
            raise DatasetError(f"{path}: field {key!r} must be finite{' and positive' if key.startswith('fl') else ''}")


def load_transforms(root: Path, modality: str) -> dict[str, Any]:
    path = root / transforms_name(modality)
    data = load_json(path)
    check_camera(data, path)
    frames = need_field(data, "frames", path, list)
    for i, frame in enumerate(frames):
        where = f"{path}: frames[{i}]"
        if not isinstance(frame, dict):
            raise DatasetError(f"{where}: must be an object")
        for key, kind in (("file_stem", str), ("time", (int, float)), ("timestamp_s", (int, float)),
                          ("sim_frame", (int, float)), ("split", str)):
            if key not in frame or not isinstance(frame[key], kind):
                raise DatasetError(f"{where}: field {key!r} missing or of the wrong type")
        if not (0.0 <= frame["time"] <= 1.0):
            raise DatasetError(f"{where}: time {frame['time']} is outside [0, 1]")
        if frame["split"] not in ("train", "test"):
            raise DatasetError(f"{where}: split must be 'train' or 'test'")
        check_pose(frame.get("transform_matrix"), where)
    return data


def read_pass_image(path: Path, pf: PassFile, shape: tuple[int, int]) -> np.ndarray:
    """One file of a pass, read once and checked: shape (H, W) from the transforms, the pass's
    dtype, finite values, and the pass's value range."""
    image = read_exr_channel(path, pf.exr_channel) if pf.ext == "exr" else read_png(path)
    expected = shape + ((3,) if pf.channels == 3 else ())
    if image.shape != expected:
        raise DatasetError(f"{path}: shape {image.shape}, expected {expected}")
    if image.dtype != pf.dtype:
        raise DatasetError(f"{path}: dtype {image.dtype}, expected {np.dtype(pf.dtype)}")
    if pf.ext == "exr" and not np.isfinite(image).all():
        raise DatasetError(f"{path}: holds NaN or Inf")
    if pf.exr_channel == "A" and (image.min() < -1e-4 or image.max() > 1 + 1e-4):
        raise DatasetError(f"{path}: smoke alpha outside [0, 1]")
    if pf.exr_channel in ("Z", "L") and image.min() < 0:
        raise DatasetError(f"{path}: negative {'depth' if pf.exr_channel == 'Z' else 'radiance'}")
    if pf.folder.endswith("smoke_mask") and not np.isin(image, (0, 255)).all():
        raise DatasetError(f"{path}: mask values must be 0 or 255")
    return image


def dataset_files(root: Path, meta: dict[str, Any]) -> list[tuple[Path, PassFile, tuple[int, int]]]:
    """Every image file the passes of dataset.json (``meta``) put in the dataset, with its pass
    and the (H, W) its modality's transforms give (a test-view pass: its test views' files)."""
    meta_path = root / DATASET_FILE
    out = []
    for modality, passes in meta["passes"].items():
        if modality not in ("rgb", "thermal") or not isinstance(passes, list):
            raise DatasetError(f"{meta_path}: field 'passes' has a bad entry {modality!r}")
        if not passes:
            continue
        transforms = load_transforms(root, modality)
        shape = (transforms["h"], transforms["w"])
        for name in passes:
            if (modality, name) not in PASS_FILES:
                raise DatasetError(f"{meta_path}: unknown pass {modality}.{name}")
            out += [(file_path(root, pf, frame["file_stem"]), pf, shape)
                    for pf in PASS_FILES[(modality, name)] for frame in transforms["frames"]
                    if has_frame(modality, name, frame["split"])]
    return out


def density_scale(meta: dict[str, Any], meta_path: Path) -> float:
    """The factor k on every smoke coefficient the dataset was rendered with (``smoke.density_scale``):
    its smoke opacity is 1 - (1 - alpha)^k of the same bake at k = 1, and k = 0 renders no smoke.
    Datasets made before the field existed were rendered at 1."""
    value = meta["smoke"].get("density_scale", 1.0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise DatasetError(f"{meta_path}: field 'smoke.density_scale' must be a finite number, at least 0, "
                           f"got {value!r}")
    return float(value)


def validate_dataset(root: Path, check_images: bool = True) -> dict[str, Any]:
    """Raise DatasetError on the first problem; return dataset.json on success. Without
    ``check_images`` every file must exist, and the reader checks each one as it reads it
    (``read_pass_image``), so no image is decoded twice."""
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: not a directory")
    meta_path = root / DATASET_FILE
    meta = load_json(meta_path)
    if meta.get("format") != FORMAT:
        raise DatasetError(f"{meta_path}: field 'format' must be {FORMAT!r}")
    if meta.get("format_version") != FORMAT_VERSION:
        raise DatasetError(f"{meta_path}: unsupported format_version {meta.get('format_version')!r}")
    for key, kind in (("scene", str), ("seed", int), ("passes", dict), ("smoke", dict), ("versions", dict),
                      ("duration_s", (int, float)), ("sim_fps", int)):
        need_field(meta, key, meta_path, kind)
    density_scale(meta, meta_path)
    for path, pf, shape in dataset_files(root, meta):
        if check_images:
            read_pass_image(path, pf, shape)
        elif not path.is_file():
            raise DatasetError(f"{path}: missing file")
    if "thermal" in meta["passes"] and meta["passes"]["thermal"]:
        sensor = need_field(meta, "thermal_sensor", meta_path, dict)
        for key in ("gain", "offset", "bits"):
            need_field(sensor, key, meta_path, (int, float))
    return meta
