"""A dataset at one smoke density made with the clean passes of another (generator.clean_reuse):
the same files, byte for byte, as generating it directly, and a clear refusal for a source that
is not the same scene at another density."""
from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

from generator.api import resolve_spec
from generator.assets import load_manifest
from generator.clean_reuse import clean_source_problem, generate_reusing_clean
from generator.errors import GeneratorError
from generator.job import resolve_asset_materials
from generator.pipeline import generate
from generator.spec import Overrides


def _at(k: float):
    spec, source = resolve_spec("demo", Overrides(frames=2, resolution=(32, 24), thermal_resolution=(16, 12),
                                                  samples=4, sim_resolution=16, density_scale=k))
    return resolve_asset_materials(spec, load_manifest(), source)


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.blender
def test_reused_clean_passes_make_the_directly_generated_dataset(tmp_path: Path) -> None:
    store = tmp_path / "bakes"
    source = generate(_at(0.5), tmp_path / "k0.5", show_progress=False, bake_store=store)
    direct = generate(_at(2.0), tmp_path / "direct", show_progress=False, bake_store=store)
    reused = generate_reusing_clean(_at(2.0), tmp_path / "reused", source, show_progress=False, bake_store=store)
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir()), "staging folder left behind"

    a, b = _files(direct), _files(reused)
    assert set(a) == set(b)
    assert any(k.startswith("thermal/clean_radiance/") for k in a) and any(k.startswith("rgb/clean/") for k in a)
    assert [k for k in a if a[k] != b[k]] == ["dataset.json"]
    meta_a, meta_b = json.loads(a["dataset.json"]), json.loads(b["dataset.json"])
    reuse = meta_b.pop("clean_reused")
    for m in (meta_a, meta_b):
        m.pop("timings_s")
    assert meta_a == meta_b
    assert reuse["from"] == "../k0.5" and reuse["source_density_scale"] == 0.5
    assert reuse["passes"] == ["rgb.clean", "thermal.clean"]
    # The smoky frames at k = 2 are not the source's: only the clean passes were copied.
    src = _files(source)
    assert b["rgb/smoky/0000.png"] != src["rgb/smoky/0000.png"]


@pytest.mark.blender
def test_a_source_that_is_not_the_same_scene_is_refused(tmp_path: Path) -> None:
    source = generate(_at(1.0), tmp_path / "k1", show_progress=False)
    assert clean_source_problem(source, _at(3.0)) is None
    assert "more than smoke.density_scale" in clean_source_problem(source, replace(_at(3.0), seed=7))
    assert "not a finished dataset" in clean_source_problem(tmp_path / "missing", _at(3.0))
    old = tmp_path / "old_code"
    shutil.copytree(source, old)
    meta = json.loads((old / "dataset.json").read_text())
    meta["code_sha256"] = "0" * 64
    (old / "dataset.json").write_text(json.dumps(meta))
    assert "other render code" in clean_source_problem(old, _at(3.0))
    with pytest.raises(GeneratorError, match=r"old_code/dataset.json: cannot provide its clean passes: .*render code"):
        generate_reusing_clean(_at(3.0), tmp_path / "k3", old, show_progress=False)
    assert not (tmp_path / "k3").exists() and not (tmp_path / ".k3.clean-reuse").exists()
