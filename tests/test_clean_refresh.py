"""Re-rendering a finished dataset's clean passes (generator.ground_truth_refresh): only the clean
files change, they match a dataset generated at the new samples from scratch, and nothing else moves."""
from __future__ import annotations

import io
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from contracts.imageio import read_exr_channel, read_png
from generator.api import resolve_spec
from generator.assets import load_manifest
from generator.ground_truth_refresh import Refresh, refresh_ground_truth, refresh_plan, with_clean_samples
from generator.errors import GeneratorError
from generator.job import make_job, make_plan, resolve_asset_materials
from generator.pipeline import generate
from generator.postprocess import psnr_u8
from generator.spec import Overrides, parse_passes


def _spec():
    spec, source = resolve_spec("demo", Overrides(frames=2, resolution=(32, 24), thermal_resolution=(16, 12),
                                                  samples=4, sim_resolution=16))
    return resolve_asset_materials(spec, load_manifest(), source)


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_a_job_without_smoke_passes_builds_no_domain(tmp_path: Path) -> None:
    spec = _spec()
    for passes, sourced in (("rgb.smoky,rgb.clean", True), ("rgb.smoke_alpha", True),
                            ("rgb.clean,thermal.clean,rgb.depth", False)):
        s = replace(spec, passes=parse_passes(passes, "test"))
        job = make_job(s, make_plan(s), load_manifest(), "test", tmp_path, 1)
        assert bool(job.sources) == sourced and bool(job.grids) == sourced, passes


@pytest.mark.blender
def test_refresh_rerenders_only_the_clean_passes(tmp_path: Path) -> None:
    spec = _spec()
    low = generate(with_clean_samples(spec, {"rgb": 2, "thermal": 2}), tmp_path / "low", show_progress=False)
    target = with_clean_samples(spec, {"rgb": 64, "thermal": 16})
    assert refresh_plan(low, target) == Refresh(resampled={"rgb": ("clean", "shadowed"), "thermal": ("clean",)},
                                                added={})
    assert refresh_plan(low, replace(target, seed=target.seed + 1)) is None  # another scene: regenerate
    with pytest.raises(GeneratorError, match="more than ground truth"):
        refresh_ground_truth(low, replace(target, seed=target.seed + 1), show_progress=False)
    before = _files(low)
    stale = tmp_path / "stale"  # a record an older spec schema wrote: regenerated, never refreshed
    stale.mkdir()
    (stale / "dataset.json").write_text((low / "dataset.json").read_text())
    (stale / "scene.yaml").write_text((low / "scene.yaml").read_text() + "retired_field: 1\n")
    assert refresh_plan(stale, target) is None

    refresh_ground_truth(low, target, show_progress=False)
    after = _files(low)
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir()), "staging folder left behind"
    clean = {k for k in before if k.startswith(("rgb/clean/", "rgb/shadowed/", "thermal/clean"))}
    assert clean and set(after) == set(before)
    changed = {k for k in before if before[k] != after[k]}
    assert changed - clean == {"dataset.json", "scene.yaml"}, changed
    meta = json.loads((low / "dataset.json").read_text())
    assert meta["spec_sha256"] == target.sha256() and refresh_plan(low, target) is None
    assert meta["render"]["rgb"]["clean_samples"] == 64
    assert meta["clean_refresh"]["clean_samples_before"] == {"rgb": 2, "thermal": 2}

    # The same frames as a dataset generated at 64 samples from scratch (with its smoke bake),
    # and far closer to them than the 2-sample frames were.
    direct = generate(target, tmp_path / "direct", show_progress=False)
    for stem in [f["file_stem"] for f in json.loads((low / "transforms_rgb.json").read_text())["frames"]]:
        ref = read_png(direct / "rgb/clean" / f"{stem}.png")
        new = psnr_u8(read_png(low / "rgb/clean" / f"{stem}.png"), ref)
        old = psnr_u8(np.asarray(Image.open(io.BytesIO(before[f"rgb/clean/{stem}.png"]))), ref)
        assert new > 45.0 and new > old + 10.0, (stem, old, new)
    for stem in [f["file_stem"] for f in json.loads((low / "transforms_thermal.json").read_text())["frames"]]:
        ref = read_exr_channel(direct / "thermal/clean_radiance" / f"{stem}.exr", "L")
        new = read_exr_channel(low / "thermal/clean_radiance" / f"{stem}.exr", "L")
        assert np.allclose(new, ref, rtol=1e-3, atol=1e-6 * float(ref.max())), stem
