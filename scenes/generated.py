"""Read a generated dataset (docs/dataset-format.md) into a ``SceneData``.

The dataset is validated as ``generate-scene --validate`` does, and every image is decoded once:
the format's validator checks the structure (dataset.json, the transforms, every file of every
pass present) without decoding images, each image the trainer uses is checked as it is read
(``contracts.dataset_format.read_pass_image``), and the files it does not use (the radiance
EXRs, the smoke alpha) are read for their check alone.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from contracts.dataset_format import (dataset_files, file_path, load_transforms, pass_file, read_pass_image,
                                      transforms_name, validate_dataset)
from contracts.errors import DatasetError
from scenes.images import box_downscale, check_finite, downscale_depth, gray, rgb01, thermal_images, working_factor
from scenes.scene import ModalityData, SceneData, set_times
from scenes.thermal_scale import LINEAR_SCALE, ThermalScaleSpec
from scenes.transforms import frames_from_transforms


def load_generated(path: Path, max_width: int, thermal_scale: ThermalScaleSpec = LINEAR_SCALE) -> SceneData:
    meta = validate_dataset(path, check_images=False)
    passes = meta["passes"]
    rgb_passes = passes.get("rgb", [])
    if "smoky" not in rgb_passes:
        raise DatasetError(f"{path / 'dataset.json'}: field 'passes.rgb' must include 'smoky'")
    read: set[Path] = set()
    rgb = _modality(path, "rgb", rgb_passes, max_width, read)
    thermal_passes = passes.get("thermal", [])
    thermal = (_modality(path, "thermal", thermal_passes, max_width, read, thermal_scale)
               if "smoky" in thermal_passes else None)
    for file, pf, shape in dataset_files(path, meta):
        if file not in read:
            read_pass_image(file, pf, shape)
    set_times(rgb, thermal, meta["duration_s"])
    smoke = meta["smoke"]
    return SceneData(
        name=meta["scene"], path=path.resolve(), rgb=rgb, thermal=thermal,
        smoke_present=bool(smoke.get("present", True)), smoke_static=bool(smoke.get("static", False)),
        mask_threshold=float(smoke.get("mask_threshold", 0.02)), synthetic=True, meta=meta)


def _modality(root: Path, modality: str, passes: list[str], max_width: int, read: set[Path],
              thermal_scale: ThermalScaleSpec = LINEAR_SCALE) -> ModalityData:
    """One camera's frames and images; every file it reads is added to ``read``."""
    data = load_transforms(root, modality)
    factor = working_factor(data["w"], max_width)
    frames = frames_from_transforms(root / transforms_name(modality), data, data["frames"], factor,
                                    default_test_every=0)
    shape = (data["h"], data["w"])

    def files(name: str, ext: str) -> list[tuple[Path, np.ndarray]]:
        pf = pass_file(modality, name, ext)
        paths = [file_path(root, pf, f.file_stem) for f in frames]
        read.update(paths)
        return [(p, read_pass_image(p, pf, shape)) for p in paths]

    def images(name: str, ext: str) -> list[np.ndarray]:
        return [a for _, a in files(name, ext)]

    def rgb_stack(name: str) -> np.ndarray:
        return np.stack([box_downscale(rgb01(a, p), factor) for p, a in files(name, "png")])

    clean = scale = masks = depth = None
    if modality == "rgb":
        smoky = rgb_stack("smoky")
        if "clean" in passes:
            clean = rgb_stack("clean")
    else:
        smoky, scale = thermal_images(np.stack([gray(a) for a in images("smoky", "png")]), factor, thermal_scale)
        if "clean" in passes:
            clean = np.stack([box_downscale(scale.apply(gray(a)), factor)[..., None] for a in images("clean", "png")])
    if "smoke_alpha" in passes:
        masks = np.stack([box_downscale(gray(a) / 255.0, factor) for a in images("smoke_alpha", "png")])
    if "depth" in passes:
        depth = np.stack([downscale_depth(a.astype(np.float64), factor) for a in images("depth", "exr")])
    check_finite(smoky, root / modality / "smoky")
    return ModalityData(name=modality, frames=frames, images=smoky.astype(np.float32),
                        clean=None if clean is None else clean.astype(np.float32),
                        masks=None if masks is None else masks.astype(np.float32),
                        depth=None if depth is None else depth.astype(np.float32),
                        scale=scale)


def load_smoke_alpha(scene: SceneData, indices: list[int]) -> np.ndarray:
    """The generator's true RGB smoke alpha (``rgb/smoke_alpha``, channel A) of the given frames,
    area-averaged to the training resolution like the masks; DatasetError names a missing file."""
    rgb = scene.rgb
    height, width = rgb.images.shape[1:3]
    pf = pass_file("rgb", "smoke_alpha", "exr")
    data = load_transforms(scene.path, "rgb")
    maps = []
    for i in indices:
        path = file_path(scene.path, pf, rgb.frames[i].file_stem)
        alpha = read_pass_image(path, pf, (data["h"], data["w"])).astype(np.float64)
        factor = alpha.shape[1] // width
        small = box_downscale(alpha, max(factor, 1))
        if small.shape[:2] != (height, width):
            raise DatasetError(f"{path}: {alpha.shape[1]}x{alpha.shape[0]} does not scale to the frames' {width}x{height}")
        maps.append(small)
    return np.stack(maps).astype(np.float32)

