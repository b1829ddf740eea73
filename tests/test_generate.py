"""generate-scene with real bpy, Mantaflow and Cycles at tiny sizes."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.ndimage import map_coordinates, maximum_filter, minimum_filter

from contracts.dataset_format import load_transforms, validate_dataset
from contracts.errors import DatasetError
from contracts.imageio import read_exr_channel, read_png
from generator.optics.planck import band_radiance
from generator.optics.slab import slab_radiance
from generator.presets import PRESET_DIR
from generator.spec import load_spec_file

pytestmark = pytest.mark.blender
REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "generator.cli"]


def run_cli(*args: str, env: dict[str, str] | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], cwd=REPO, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


def demo_spec(tmp_path: Path, name: str = "scene.yaml", **changes) -> Path:
    data = yaml.safe_load((PRESET_DIR / "demo.yaml").read_text())
    for dotted, value in changes.items():
        node = data
        *parents, leaf = dotted.split("__")
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node[key]
        node[leaf] = value
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def test_demo_dataset_is_valid(demo_dataset: Path) -> None:
    meta = validate_dataset(demo_dataset)
    assert meta["smoke"] == {**meta["smoke"], "present": True, "fire": False, "grids": ["density"]}
    rgb, thermal = load_transforms(demo_dataset, "rgb"), load_transforms(demo_dataset, "thermal")
    assert len(rgb["frames"]) == 6 and 2 <= len(thermal["frames"]) < 6
    assert thermal["w"] < rgb["w"] and thermal["fps"] != rgb["fps"]
    assert meta["versions"]["bpy"].startswith("4.5") and meta["seed"] == 0
    assert meta["timings_s"]["bake"] > 0 and all(v > 0 for v in meta["timings_s"]["render"].values())
    # The recorded scene.yaml is a spec in its own right: it loads back to the spec that was hashed.
    assert load_spec_file(demo_dataset / "scene.yaml").sha256() == meta["spec_sha256"]


def test_validator_rejects_broken_data(demo_dataset: Path, tmp_path: Path) -> None:
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(demo_dataset, broken)
    transforms = json.loads((broken / "transforms_rgb.json").read_text())
    transforms["frames"][1]["transform_matrix"][0][0] = float("nan")
    (broken / "transforms_rgb.json").write_text(json.dumps(transforms))
    with pytest.raises(DatasetError, match=r"transforms_rgb.json: frames\[1\].transform_matrix holds NaN"):
        validate_dataset(broken)
    shutil.copy(demo_dataset / "transforms_rgb.json", broken / "transforms_rgb.json")
    (broken / "rgb" / "depth" / "0002.exr").write_bytes(b"not an exr")
    with pytest.raises(DatasetError, match=r"0002.exr: not a readable EXR"):
        validate_dataset(broken)
    result = run_cli("--validate", str(broken))
    assert result.returncode == 2 and "Traceback" not in result.stderr and "0002.exr" in result.stderr


def _rgb(d: Path, folder: str, stem: str) -> np.ndarray:
    return read_png(d / "rgb" / folder / f"{stem}.png").astype(np.float64) / 255.0


def test_smoke_changes_rgb_inside_the_mask_only(demo_dataset: Path) -> None:
    inside, outside = [], []
    for frame in load_transforms(demo_dataset, "rgb")["frames"]:
        stem = frame["file_stem"]
        diff = np.abs(_rgb(demo_dataset, "smoky", stem) - _rgb(demo_dataset, "clean", stem)).mean(axis=-1)
        alpha = read_exr_channel(demo_dataset / "rgb" / "smoke_alpha" / f"{stem}.exr", "A")
        inside.append(diff[alpha > 0.3].mean())
        outside.append(diff[alpha < 1e-3].mean())
    # Outside the smoke only its shadow and scattered light differ, at the level of render noise.
    assert np.mean(inside) > 0.08
    assert np.mean(outside) < 0.03
    assert np.mean(inside) > 5 * np.mean(outside)


def test_thermal_sees_through_the_smoke(demo_dataset: Path) -> None:
    meta = json.loads((demo_dataset / "dataset.json").read_text())
    rgb_alpha = [read_exr_channel(p, "A") for p in sorted((demo_dataset / "rgb" / "smoke_alpha").glob("*.exr"))]
    th_alpha = [read_exr_channel(p, "A") for p in sorted((demo_dataset / "thermal" / "smoke_alpha").glob("*.exr"))]
    # Both cameras frame the same plume from 6 cm apart, so whole-image means compare like for like.
    rgb_mean, thermal_mean = np.mean([a.mean() for a in rgb_alpha]), np.mean([a.mean() for a in th_alpha])
    assert rgb_mean > 0.1 and max(a.max() for a in rgb_alpha) > 0.95
    assert thermal_mean < 0.2 * rgb_mean
    assert max(a.max() for a in th_alpha) < 0.5
    # The ratio of optical depths is the Mie ratio: for thin thermal smoke alpha ≈ ratio * tau_visible.
    assert meta["optics"]["sigma_ratio_lwir_over_visible"] < 0.1


def _backproject(depth: np.ndarray, t: dict, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v, u = np.nonzero(depth > 0)
    d = depth[v, u]
    cam = np.stack([(u + 0.5 - t["cx"]) / t["fl_x"] * d, -(v + 0.5 - t["cy"]) / t["fl_y"] * d, -d, np.ones_like(d)])
    return (c2w @ cam)[:3].T, d


def test_depth_poses_and_intrinsics_agree_across_views(demo_dataset: Path) -> None:
    t = load_transforms(demo_dataset, "rgb")
    frames = t["frames"]
    depth = [read_exr_channel(demo_dataset / "rgb" / "depth" / f"{f['file_stem']}.exr", "Z") for f in frames]
    checked = 0
    for a, b in ((0, 1), (1, 3), (2, 5)):
        points, _ = _backproject(depth[a], t, np.asarray(frames[a]["transform_matrix"]))
        w2c = np.linalg.inv(np.asarray(frames[b]["transform_matrix"]))
        cam = (w2c[:3, :3] @ points.T).T + w2c[:3, 3]
        z = -cam[:, 2]
        u = cam[:, 0] / z * t["fl_x"] + t["cx"] - 0.5
        v = -cam[:, 1] / z * t["fl_y"] + t["cy"] - 0.5
        ok = (z > 0) & (u >= 0) & (u <= t["w"] - 1) & (v >= 0) & (v <= t["h"] - 1)
        # Bilinear lookup at the projected position, only where the four taps lie on one smooth surface.
        seen = map_coordinates(depth[b], [v[ok], u[ok]], order=1)
        lo = minimum_filter(depth[b], size=2, origin=-1)
        hit = (lo > 0) & (maximum_filter(depth[b], size=2, origin=-1) < 1.05 * lo)
        seen = np.where(hit[np.floor(v[ok]).astype(int), np.floor(u[ok]).astype(int)], seen, 0.0)
        valid = seen > 0
        rel = (seen[valid] - z[ok][valid]) / z[ok][valid]
        # A point agrees with view b's depth or is occluded there (b sees something nearer);
        # b seeing *past* a point it should see would mean inconsistent poses or depth.
        assert np.median(np.abs(rel)) < 1e-3
        assert np.mean(np.abs(rel) < 0.01) > 0.5
        assert np.mean(rel > 0.01) < 0.03
        checked += int(ok.sum())
    assert checked > 1000


def _image(path: Path) -> np.ndarray:
    return (read_png(path) if path.suffix == ".png" else read_exr_channel(path, "L")).astype(np.float64)


def test_same_spec_and_seed_reproduce_the_dataset(demo_dataset: Path, tmp_path: Path) -> None:
    runs = []
    for name in ("one", "two"):
        out = tmp_path / name
        result = run_cli("--preset", "demo", "--out", str(out), "--frames", "2",
                         "--passes", "rgb.smoky,thermal.smoky", "--quiet")
        assert result.returncode == 0, result.stderr
        runs.append(out)
    files = sorted(p.relative_to(runs[0]) for p in runs[0].rglob("*") if p.suffix in (".png", ".exr"))
    assert len(files) == 2 + 2 * 1
    identical = 0
    for rel in files:
        a, b = (runs[0] / rel).read_bytes(), (runs[1] / rel).read_bytes()
        identical += a == b
        if a != b:  # seen only under heavy CPU contention (cause not isolated; docs/generator.md)
            x, y = (_image(r / rel) for r in runs)
            peak = 255.0 if rel.suffix == ".png" else float(np.abs(x).max())
            assert 10 * np.log10(peak**2 / np.mean((x - y) ** 2)) > 40.0, rel
    for name in ("transforms_rgb.json", "transforms_thermal.json", "scene.yaml"):
        assert (runs[0] / name).read_bytes() == (runs[1] / name).read_bytes(), name
    print(f"{identical}/{len(files)} files byte-identical")
    # Only what was asked for is rendered.
    assert sorted(p.name for p in (runs[0] / "rgb").iterdir()) == ["smoky"]
    assert sorted(p.name for p in (runs[0] / "thermal").iterdir()) == ["smoky", "smoky_radiance"]
    assert json.loads((runs[0] / "dataset.json").read_text())["passes"] == {"rgb": ["smoky"], "thermal": ["smoky"]}
    # Another pass selection renders the same frame to within one 8-bit level (Cycles
    # state differs slightly with what rendered before); thermal radiance is unaffected.
    a = read_png(runs[0] / "rgb/smoky/0000.png").astype(int)
    b = read_png(demo_dataset / "rgb/smoky/0000.png").astype(int)
    assert np.abs(a - b).max() <= 1 and (a != b).mean() < 0.01


@pytest.mark.parametrize("args, needle", [
    (["--preset", "nope"], "--preset: nope: unknown preset; available: "),
    (["SPEC", "--frames", "0"], "--frames: must be positive"),
    (["SPEC", "--resolution=-64x48"], "--resolution: must be positive"),
])
def test_bad_cli_input_is_one_clear_line(tmp_path: Path, args: list[str], needle: str) -> None:
    args = [str(demo_spec(tmp_path)) if a == "SPEC" else a for a in args]
    out = tmp_path / "out"
    result = run_cli(*args, "--out", str(out))
    assert result.returncode == 2
    assert needle in result.stderr and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_bad_spec_files_name_file_and_field(tmp_path: Path) -> None:
    malformed = tmp_path / "malformed.yaml"
    malformed.write_text("name: demo\nobjects: [\n")
    unknown_asset = demo_spec(tmp_path, "unknown_asset.yaml", objects__1__asset="teapot")
    for spec, needle in ((malformed, "malformed.yaml: malformed YAML at line"),
                         (unknown_asset, "unknown_asset.yaml: objects[1].asset: unknown asset 'teapot'")):
        result = run_cli(str(spec), "--out", str(tmp_path / "out"))
        assert result.returncode == 2 and needle in result.stderr, result.stderr
        assert "Traceback" not in result.stderr
    assert not (tmp_path / "out").exists()


def _tiny_mesh_manifest(tmp_path: Path, sha: str | None = None) -> Path:
    import trimesh

    mesh_path = tmp_path / "block.ply"
    trimesh.creation.box(extents=(40.0, 40.0, 60.0)).export(mesh_path)
    from generator.assets import sha256_of

    manifest = yaml.safe_load((REPO / "assets_manifest.yaml").read_text())
    manifest["assets"]["block"] = {"kind": "file", "path": "block.ply", "units": "cm",
                                   "sha256": sha or sha256_of(mesh_path), "license": "CC0-1.0",
                                   "provenance": "trimesh.creation.box in this test"}
    path = tmp_path / "manifest.yaml"
    path.write_text(yaml.safe_dump(manifest))
    return path


def test_checksum_mismatch_is_refused(tmp_path: Path) -> None:
    manifest = _tiny_mesh_manifest(tmp_path, sha="0" * 64)
    spec = demo_spec(tmp_path, objects__1__asset="block")
    result = run_cli(str(spec), "--out", str(tmp_path / "out"), env={"SMOKESEER_ASSETS_MANIFEST": str(manifest)})
    assert result.returncode == 2 and "block.ply: sha256 mismatch for asset 'block'" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "out").exists()


def test_worker_crash_reports_its_log_and_leaves_no_dataset(tmp_path: Path) -> None:
    spec = demo_spec(tmp_path, objects__2__params={"radius": "large"})
    out = tmp_path / "out"
    result = run_cli(str(spec), "--out", str(out), "--quiet")
    assert result.returncode == 2
    line = result.stderr.strip().splitlines()[-1]
    assert "Blender worker failed (bake): ValueError" in line and "Full log: " in line
    log = Path(line.split("Full log: ")[1])
    assert log.is_file() and "Traceback" in log.read_text()
    assert not out.exists()


def test_no_fire_means_no_flame_grid_and_no_flame_nodes(tmp_path: Path) -> None:
    """Smoke-only: no flame grid, no flame lookup, no RGB glow (the LWIR smoke emits at ambient
    temperature). Fire: the flame grid drives RGB glow and LWIR emission."""
    script = (
        "import bpy, json, sys\n"
        "from blender import materials\n"
        "from generator.api import resolve_spec\n"
        "from generator.assets import load_manifest\n"
        "from generator.job import make_job, make_plan\n"
        "from pathlib import Path\n"
        "out = {}\n"
        "for name in sys.argv[1:]:\n"
        "    spec, src = resolve_spec(name)\n"
        "    job = make_job(spec, make_plan(spec), load_manifest(), src, Path(sys.argv[0]).parent, 1)\n"
        "    kinds = {m.name: sorted({n.bl_idname for n in m.node_tree.nodes} | {'attr:' + n.attribute_name\n"
        "                                for n in m.node_tree.nodes if n.bl_idname == 'ShaderNodeAttribute'}) for m in\n"
        "             (materials.thermal_smoke(job.smoke_thermal), materials.rgb_smoke(job.smoke_rgb))}\n"
        "    out[name] = {'grids': list(job.grids), 'nodes': kinds}\n"
        "print(json.dumps(out))\n"
    )
    fire = demo_spec(tmp_path, "fire.yaml", sources__0__type="fire", sources__0__temperature_k=1100.0)
    result = subprocess.run([sys.executable, "-c", script, "demo", str(fire)], cwd=REPO, capture_output=True,
                            text=True, timeout=300)
    report = json.loads(result.stdout.strip().splitlines()[-1])
    smoke_only, with_fire = report["demo"], report[str(fire)]
    assert smoke_only["grids"] == ["density"]
    assert all("attr:flame" not in nodes for nodes in smoke_only["nodes"].values())
    assert "ShaderNodeEmission" not in smoke_only["nodes"]["smoke.rgb"]
    assert "ShaderNodeEmission" in smoke_only["nodes"]["smoke.thermal"]
    assert with_fire["grids"] == ["density", "flame"]
    assert all("ShaderNodeEmission" in nodes and "attr:flame" in nodes for nodes in with_fire["nodes"].values())


def test_thermal_render_matches_the_analytic_slab(tmp_path: Path) -> None:
    """Cycles + our materials (absorption and Kirchhoff emission) against L = tau*L_s + (1-tau)*L(T_smoke)."""
    l_surf, ambient_k = float(band_radiance(330.0)), 293.15
    cases = [(0.2, 0.5), (1.0, 1.0), (2.0, 1.5)]
    out = tmp_path / "slab.json"
    args = [str(v) for case in cases for v in case]
    result = subprocess.run([sys.executable, str(REPO / "tests" / "blender_scripts" / "thermal_slab.py"), str(out),
                             str(l_surf), str(float(band_radiance(ambient_k))), *args], cwd=REPO,
                            capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert result.returncode == 0, result.stderr[-2000:]
    for row in json.loads(out.read_text()):
        tau = row["k"] * row["d"]
        expected = float(slab_radiance(l_surf, tau, ambient_k))
        assert row["radiance"] == pytest.approx(expected, rel=2e-3), row
        assert row["alpha"] == pytest.approx(1 - np.exp(-tau), abs=2e-3)


@pytest.mark.slow
def test_fire_smoke_glows_in_thermal(tmp_path: Path) -> None:
    spec = demo_spec(tmp_path, sources__0__type="both", sources__0__temperature_k=1100.0)
    out = tmp_path / "fire"
    result = run_cli(str(spec), "--out", str(out), "--frames", "2", "--passes", "thermal.smoky,thermal.clean",
                     "--quiet")
    assert result.returncode == 0, result.stderr
    smoky = read_exr_channel(out / "thermal" / "smoky_radiance" / "0000.exr", "L")
    clean = read_exr_channel(out / "thermal" / "clean_radiance" / "0000.exr", "L")
    assert (smoky - clean).max() > 0.2 * clean.mean()
    assert json.loads((out / "dataset.json").read_text())["smoke"]["grids"] == ["density", "flame"]


@pytest.mark.slow
def test_interrupted_run_resumes_without_redoing_frames(tmp_path: Path) -> None:
    out = tmp_path / "resumed"
    staging = tmp_path / ".resumed.partial"
    args = [*CLI, "--preset", "demo", "--out", str(out), "--frames", "4", "--quiet"]
    proc = subprocess.Popen(args, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            process_group=0)  # its own group, so killpg reaches the Blender worker
    deadline = time.time() + 300
    while time.time() < deadline and not any((staging / "raw" / "rgb" / "clean").glob("*.png")):
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not out.exists(), "a killed run must not leave a dataset at the output path"
    assert (staging / "scene.blend").exists()
    result = run_cli("--preset", "demo", "--out", str(out), "--frames", "4", "--quiet")
    assert result.returncode == 0, result.stderr
    validate_dataset(out)
    assert not staging.exists()
    assert "bake reused" in result.stderr
    reused = re.search(r"rendered (\d+) images, reused (\d+) from an earlier run", result.stderr)
    assert reused and int(reused.group(2)) >= 1, result.stderr
    meta = json.loads((out / "dataset.json").read_text())
    assert meta["timings_s"]["bake"] > 0, "the first run's bake time is kept across the resume"


def test_smoke_free_scene_generates_without_smoke_passes(tmp_path: Path) -> None:
    spec = demo_spec(tmp_path, sources=[])
    out = tmp_path / "clear"
    result = run_cli(str(spec), "--out", str(out), "--frames", "2", "--resolution", "32x24", "--quiet")
    assert result.returncode == 0, result.stderr
    meta = validate_dataset(out)
    assert meta["smoke"]["present"] is False and meta["smoke"]["grids"] == []
    assert meta["passes"]["rgb"] == ["smoky", "clean", "depth"]
    # Both are the smoke-free scene; the clean pass has its own, higher sample count, so the two
    # differ only by Monte Carlo noise.
    smoky, clean = (read_png(out / f"rgb/{name}/0000.png").astype(np.float64) / 255 for name in ("smoky", "clean"))
    assert meta["render"]["rgb"]["clean_samples"] > meta["render"]["rgb"]["samples"]
    assert 10 * np.log10(1 / np.mean((smoky - clean) ** 2)) > 30
