"""The clean (smoke-free) passes render at the camera's own `clean_samples`, not at `samples`."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from contracts.imageio import read_png
from generator.api import resolve_spec
from generator.pipeline import generate
from generator.postprocess import psnr_u8
from generator.spec import Overrides, parse_passes


@pytest.mark.blender
def test_clean_pass_converges_with_clean_samples(tmp_path: Path) -> None:
    """Smoky samples fixed at 4; only clean_samples changes, and the clean image converges with it."""
    spec, _ = resolve_spec("demo", Overrides(frames=1, resolution=(32, 24), samples=4))
    spec = replace(spec, sources=(), passes=parse_passes("rgb.clean", "test"))

    def clean_image(clean_samples: int) -> np.ndarray:
        rig = spec.rig
        scene = replace(spec, rig=replace(rig, rgb=replace(rig.rgb, clean_samples=clean_samples)))
        out = generate(scene, tmp_path / f"s{clean_samples}", show_progress=False)
        return read_png(next((out / "rgb" / "clean").glob("*.png")))

    reference = clean_image(1024)
    coarse, fine = psnr_u8(clean_image(4), reference), psnr_u8(clean_image(256), reference)
    assert fine > coarse + 10.0, (coarse, fine)
