"""Read a generated dataset (docs/dataset-format.md) into a ``SceneData``.

The format's validator checks the structure (dataset.json, the transforms, every file of every
pass present) without decoding images; each image the trainer uses is then read once and
checked as it is read (``contracts.dataset_format.read_pass_image``). Files the trainer does
not use (the radiance EXRs, thermal smoke alpha) are checked by ``generate-scene --validate``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from contracts.dataset_format import (file_path, load_transforms, pass_file, read_pass_image, transforms_name,
                                      validate_dataset)
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
    rgb = _modality(path, "rgb", rgb_passes, max_width)
    thermal_passes = passes.get("thermal", [])
    thermal = (_modality(path, "thermal", thermal_passes, max_width, thermal_scale)
               if "smoky" in thermal_passes else None)
    set_times(rgb, thermal, meta["duration_s"])
    smoke = meta["smoke"]
    return SceneData(
        name=meta["scene"], path=path.resolve(), rgb=rgb, thermal=thermal,
        smoke_present=bool(smoke.get("present", True)), smoke_static=bool(smoke.get("static", False)),
        mask_threshold=float(smoke.get("mask_threshold", 0.02)), synthetic=True, meta=meta)


def _modality(root: Path, modality: str, passes: list[str], max_width: int,
              thermal_scale: ThermalScaleSpec = LINEAR_SCALE) -> ModalityData:
    data = load_transforms(root, modality)
    factor = working_factor(data["w"], max_width)
    frames = frames_from_transforms(root / transforms_name(modality), data, data["frames"], factor,
                                    default_test_every=0)
    shape = (data["h"], data["w"])

    def read(name: str, ext: str) -> list[np.ndarray]:
        pf = pass_file(modality, name, ext)
        return [read_pass_image(file_path(root, pf, f.file_stem), pf, shape) for f in frames]

    def rgb_stack(name: str) -> np.ndarray:
        pf = pass_file(modality, name, "png")
        return np.stack([box_downscale(rgb01(read_pass_image(p, pf, shape), p), factor)
                         for p in (file_path(root, pf, f.file_stem) for f in frames)])

    clean = scale = masks = depth = None
    if modality == "rgb":
        images = rgb_stack("smoky")
        if "clean" in passes:
            clean = rgb_stack("clean")
    else:
        images, scale = thermal_images(np.stack([gray(a) for a in read("smoky", "png")]), factor, thermal_scale)
        if "clean" in passes:
            clean = np.stack([box_downscale(scale.apply(gray(a)), factor)[..., None] for a in read("clean", "png")])
    if "smoke_alpha" in passes:
        masks = np.stack([box_downscale(gray(a) / 255.0, factor) for a in read("smoke_alpha", "png")])
    if "depth" in passes:
        depth = np.stack([downscale_depth(a.astype(np.float64), factor) for a in read("depth", "exr")])
    check_finite(images, root / modality / "smoky")
    return ModalityData(name=modality, frames=frames, images=images.astype(np.float32),
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

