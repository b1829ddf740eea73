"""Read a generated dataset (docs/dataset-format.md) into a ``SceneData``.

The dataset is validated as ``generate-scene --validate`` does, and every image is decoded once:
the format's validator checks the structure (dataset.json, the transforms, every file of every
pass present) without decoding images, each image the trainer uses is checked as it is read
(``contracts.dataset_format.read_pass_image``), and the other inputs (the radiance EXRs) are read
for their check alone.

Ground truth a real capture lacks (clean frames, depth, smoke alpha;
``contracts.dataset_format.GROUND_TRUTH_FOLDERS``) is read for the evaluation frames' scores
alone: the training frames' files are never opened, so nothing in training can use them.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from contracts.dataset_format import (GROUND_TRUTH_FOLDERS, SPEC_FILE, dataset_files, file_path, has_frame,
                                      load_transforms, pass_file, read_pass_image, transforms_name, validate_dataset)
from contracts.errors import DatasetError
from scenes.cameras import GL_TO_CV_AXES
from scenes.images import box_downscale, check_finite, downscale_depth, gray, rgb01, thermal_images, working_factor
from scenes.rig import RigExtrinsic
from scenes.scene import ModalityData, SceneData, set_times
from scenes.splits import hold_out_validation
from scenes.thermal_scale import LINEAR_SCALE, ThermalScaleSpec
from scenes.transforms import frames_from_transforms


def load_generated(path: Path, max_width: int, thermal_scale: ThermalScaleSpec = LINEAR_SCALE,
                   validation_every: int = 0, all_ground_truth: bool = False) -> SceneData:
    meta = validate_dataset(path, check_images=False)
    passes = meta["passes"]
    rgb_passes = passes.get("rgb", [])
    if "smoky" not in rgb_passes:
        raise DatasetError(f"{path / 'dataset.json'}: field 'passes.rgb' must include 'smoky'")
    read: set[Path] = set()
    rgb = _modality(path, "rgb", rgb_passes, max_width, read, all_ground_truth, validation_every=validation_every)
    thermal_passes = passes.get("thermal", [])
    thermal = (_modality(path, "thermal", thermal_passes, max_width, read, all_ground_truth, thermal_scale)
               if "smoky" in thermal_passes else None)
    for file, pf, shape in dataset_files(path, meta):
        if file not in read and (all_ground_truth or pf.folder not in GROUND_TRUTH_FOLDERS):
            read_pass_image(file, pf, shape)
    set_times(rgb, thermal, meta["duration_s"])
    smoke = meta["smoke"]
    return SceneData(
        name=meta["scene"], path=path.resolve(), rgb=rgb, thermal=thermal,
        smoke_present=bool(smoke.get("present", True)), smoke_static=bool(smoke.get("static", False)),
        mask_threshold=float(smoke.get("mask_threshold", 0.02)), synthetic=True, meta=meta)


def _modality(root: Path, modality: str, passes: list[str], max_width: int, read: set[Path],
              all_ground_truth: bool, thermal_scale: ThermalScaleSpec = LINEAR_SCALE,
              validation_every: int = 0) -> ModalityData:
    """One camera's frames and images; every file it reads is added to ``read``. Without
    ``all_ground_truth`` the RGB clean and shadowed frames and depth are read for the evaluation
    frames only, and the thermal ones not at all (nothing scores them)."""
    data = load_transforms(root, modality)
    factor = working_factor(data["w"], max_width)
    frames = frames_from_transforms(root / transforms_name(modality), data, data["frames"], factor,
                                    default_test_every=0)
    shape = (data["h"], data["w"])
    if modality == "rgb":
        hold_out_validation(frames, validation_every)

    def files(name: str, ext: str, subset: list[int] | None = None) -> list[tuple[Path, np.ndarray]]:
        pf = pass_file(modality, name, ext)
        paths = [file_path(root, pf, frames[i].file_stem) for i in (range(len(frames)) if subset is None else subset)]
        read.update(paths)
        return [(p, read_pass_image(p, pf, shape)) for p in paths]

    def images(name: str, ext: str) -> list[np.ndarray]:
        return [a for _, a in files(name, ext)]

    def scoring_only(name: str, ext: str, convert: Callable[[Path, np.ndarray], np.ndarray]) -> np.ndarray | None:
        """A ground-truth pass read for the evaluation frames alone (a test-view pass: the test
        frames); the other frames' slots hold NaN, and their files are never opened. None when
        no such frame has the pass."""
        subset = [i for i in evaluation if has_frame(modality, name, frames[i].split)]
        if not subset:
            return None
        decoded = [convert(p, a) for p, a in files(name, ext, subset)]
        out = np.full((len(frames), *decoded[0].shape), np.nan, dtype=np.float32)
        for i, a in zip(subset, decoded):
            out[i] = a
        return out

    evaluation = [i for i, f in enumerate(frames) if all_ground_truth or f.split != "train"]
    clean = shadowed = scale = masks = depth = None
    if modality == "rgb":
        smoky = np.stack([box_downscale(rgb01(a, p), factor) for p, a in files("smoky", "png")])
        if "clean" in passes:
            clean = scoring_only("clean", "png", lambda p, a: box_downscale(rgb01(a, p), factor))
        if "shadowed" in passes:
            shadowed = scoring_only("shadowed", "png", lambda p, a: box_downscale(rgb01(a, p), factor))
    else:
        smoky, scale = thermal_images(np.stack([gray(a) for a in images("smoky", "png")]), factor, thermal_scale)
        if "clean" in passes and all_ground_truth:
            clean = np.stack([box_downscale(scale.apply(gray(a)), factor)[..., None]
                              for a in images("clean", "png")]).astype(np.float32)
    if "depth" in passes and (modality == "rgb" or all_ground_truth):
        depth = scoring_only("depth", "exr", lambda p, a: downscale_depth(a.astype(np.float64), factor))
    if "smoke_alpha" in passes:
        masks = np.stack([box_downscale(gray(a) / 255.0, factor) for a in images("smoke_alpha", "png")])
    check_finite(smoky, root / modality / "smoky")
    return ModalityData(name=modality, frames=frames, images=smoky.astype(np.float32),
                        clean=clean, shadowed=shadowed, masks=None if masks is None else masks.astype(np.float32),
                        depth=depth, scale=scale)


def spec_rig(root: Path) -> RigExtrinsic:
    """The generator's rig as a calibration would give it: the thermal camera turned as the RGB
    one, its centre at ``rig.thermal.baseline_m`` (RGB camera axes, metres) of the dataset's
    ``scene.yaml``; the poses' scale is left unknown (``metres_per_unit``), as for SfM poses."""
    spec_path = Path(root) / SPEC_FILE
    try:
        baseline = yaml.safe_load(spec_path.read_text())["rig"]["thermal"]["baseline_m"]
        lever = np.asarray(baseline, dtype=np.float64)
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
        raise DatasetError(f"{spec_path}: field 'rig.thermal.baseline_m' unreadable ({exc})") from None
    if lever.shape != (3,) or not np.all(np.isfinite(lever)):
        raise DatasetError(f"{spec_path}: field 'rig.thermal.baseline_m' must be 3 finite numbers")
    return RigExtrinsic(np.eye(3), lever * GL_TO_CV_AXES + 0.0)  # + 0.0: no -0.0
