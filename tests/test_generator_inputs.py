"""Issue 15, generator side: bad input gives one clear line and leaves nothing behind; SIGTERM
behaves like Ctrl-C; every command-line option has help."""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from contracts.errors import DatasetError
from contracts.imageio import read_exr_channel, write_exr
from generator import benchmark_cli, cli, contact_sheet
from generator.assets import load_manifest, load_mesh, sha256_of
from generator.errors import AssetError, SpecError
from generator.presets import PRESET_DIR

REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "generator.cli"]


@pytest.mark.parametrize("keep_bytes", [100, 300, 400, 1000])
def test_truncated_exr_is_one_line_naming_the_file(tmp_path: Path, keep_bytes: int,
                                                   capfd: pytest.CaptureFixture) -> None:
    path = tmp_path / "0001.exr"
    rng = np.random.default_rng(0)
    write_exr(path, {"A": rng.random((48, 64)).astype(np.float32)})
    path.write_bytes(path.read_bytes()[:keep_bytes])
    with pytest.raises(DatasetError) as info:
        read_exr_channel(path, "A")
    message = str(info.value)
    assert message.startswith(f"{path}: not a readable EXR image, truncated or corrupt")
    assert "\n" not in message and "has no channel" not in message
    out, err = capfd.readouterr()
    assert out == "" and err == "", "the OpenEXR library's own messages must not leak"


def _manifest_with_block(tmp_path: Path, sha: object) -> Path:
    import trimesh

    trimesh.creation.box(extents=(40.0, 40.0, 60.0)).export(tmp_path / "block.ply")
    manifest = yaml.safe_load((REPO / "assets_manifest.yaml").read_text())
    manifest["assets"]["block"] = {"kind": "file", "path": "block.ply", "units": "cm", "sha256": sha,
                                   "license": "CC0-1.0", "provenance": "trimesh.creation.box in this test"}
    path = tmp_path / "manifest.yaml"
    path.write_text(yaml.safe_dump(manifest))
    return path


def test_sha256_mismatch_prints_both_full_digests(tmp_path: Path) -> None:
    wrong = "0" * 63 + "1"
    manifest = load_manifest(_manifest_with_block(tmp_path, wrong))
    with pytest.raises(AssetError) as info:
        load_mesh(manifest.assets["block"])
    assert f"manifest says {wrong}, file is {sha256_of(tmp_path / 'block.ply')}" in str(info.value)


def test_digest_read_as_a_number_says_so(tmp_path: Path) -> None:
    path = _manifest_with_block(tmp_path, "x")
    path.write_text(path.read_text().replace("sha256: x", "sha256: " + "1" * 64))  # digits only: an int
    with pytest.raises(SpecError, match=r"assets.block.sha256: YAML read this digest as a number .*in quotes"):
        load_manifest(path)


def _spec(tmp_path: Path, asset: str) -> Path:
    data = yaml.safe_load((PRESET_DIR / "demo.yaml").read_text())
    data["objects"][1]["asset"] = asset  # the crate keeps its own material
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("case, needle", [
    ("unknown", "objects[1].asset: unknown asset 'teapot'"),
    ("mismatch", "sha256 mismatch for asset 'block'"),
    ("missing", "asset 'block' is missing"),
])
def test_asset_errors_leave_no_staging_folder(tmp_path: Path, case: str, needle: str) -> None:
    manifest = _manifest_with_block(tmp_path, "0" * 64 if case == "mismatch" else "x")
    if case != "mismatch":
        text = manifest.read_text().replace("sha256: x", f"sha256: {sha256_of(tmp_path / 'block.ply')}")
        manifest.write_text(text)
    if case == "missing":
        (tmp_path / "block.ply").unlink()
    spec = _spec(tmp_path, "teapot" if case == "unknown" else "block")
    out = tmp_path / "out"
    result = subprocess.run([*CLI, str(spec), "--out", str(out), "--quiet"], cwd=REPO, capture_output=True,
                            text=True, timeout=300, env={**os.environ, "SMOKESEER_ASSETS_MANIFEST": str(manifest)})
    assert result.returncode == 2 and needle in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
    assert not out.exists() and not (tmp_path / ".out.partial").exists()


@pytest.mark.parametrize("args, needle", [
    (["--resolution", "100000x75000"], "command line: --resolution: 100000x75000 needs about 447 GiB to render one frame"),
    (["--frames", "100000", "--resolution", "4000x3000"], "command line: --resolution: 5.2e+14 pixel-samples in all"),
    (["--thermal-resolution", "16000x12000"], "--thermal-resolution: 16000x12000 (x2 supersampled) needs about 46 GiB"),
])
def test_renders_too_big_to_fit_or_finish_are_refused_before_any_work(tmp_path: Path, args: list[str],
                                                                      needle: str) -> None:
    """The demo at 7.5 gigapixels (or 10^14 pixel-samples) is refused with the estimate, naming
    the option, before Blender starts: exit 2, one line, nothing written."""
    out = tmp_path / "out"
    start = time.perf_counter()
    result = subprocess.run([*CLI, "--preset", "demo", *args, "--out", str(out), "--quiet"], cwd=REPO,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and needle in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
    assert not out.exists() and not (tmp_path / ".out.partial").exists()
    assert time.perf_counter() - start < 60


def _options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions if not isinstance(a, argparse._HelpAction)]


@pytest.mark.parametrize("module", [cli, benchmark_cli, contact_sheet])
def test_every_option_has_help(module) -> None:
    parser = module.build_parser()
    missing = [a.dest for a in _options(parser) if not (a.help and a.help.strip())]
    assert not missing, f"{parser.prog}: options without help: {missing}"


@pytest.mark.blender
@pytest.mark.slow
def test_sigterm_stops_like_ctrl_c_and_resumes(tmp_path: Path) -> None:
    out, staging = tmp_path / "demo", tmp_path / ".demo.partial"
    args = [*CLI, "--preset", "demo", "--out", str(out), "--frames", "4", "--quiet"]
    proc = subprocess.Popen(args, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    while time.time() < deadline and not any((staging / "raw" / "rgb" / "smoky").glob("*.png")):
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM
    assert stderr.strip().splitlines()[-1] == "generate-scene: interrupted; run the same command again to resume"
    assert not out.exists() and (staging / "scene.blend").exists()
    worker_log = (staging / "logs" / "worker.log").read_text()
    assert '@@done {"stage": "render"' not in worker_log, "the render worker must stop with its parent"
    resumed = subprocess.run(args, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "bake reused" in resumed.stderr and not staging.exists()


def test_staging_folder_is_reused_only_for_the_same_spec_and_render_code(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """Images rendered by older code are not this code's output: a resume after a code change
    must start over, and the log must say it was the code, not the spec, that differed."""
    import dataclasses
    import logging

    from contracts.source import module_closure
    from generator import pipeline
    from generator.spec import load_spec_file

    spec = load_spec_file(PRESET_DIR / "demo.yaml")
    out = tmp_path / "scene"
    monkeypatch.setattr(pipeline, "code_digest", lambda *roots: "a" * 64)
    work = pipeline._staging(out, spec, pipeline.render_code_digest())
    old_image = work / "raw" / "0000.png"
    old_image.parent.mkdir()
    old_image.write_bytes(b"rendered by code a")
    assert pipeline._staging(out, spec, pipeline.render_code_digest()) == work and old_image.exists()

    monkeypatch.setattr(pipeline, "code_digest", lambda *roots: "b" * 64)
    with caplog.at_level(logging.INFO, logger="generate-scene"):
        work = pipeline._staging(out, spec, pipeline.render_code_digest())
    assert not old_image.exists(), "a staging folder from other render code was reused"
    assert "different generator code" in caplog.text and "different spec" not in caplog.text
    assert (work / "dataset").is_dir()

    changed = dataclasses.replace(spec, seed=spec.seed + 1)
    with caplog.at_level(logging.INFO, logger="generate-scene"):
        pipeline._staging(out, changed, pipeline.render_code_digest())
    assert "different spec" in caplog.text
    # the digest's roots reach the modules that actually render and post-process
    names = {m.name for m in module_closure("generator.pipeline", "blender.worker")}
    assert {"blender.render", "blender.scene", "generator.postprocess", "generator.optics.sensor"} <= names
