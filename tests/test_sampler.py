"""The scene sampler (issue 101): 200 drawn specs are valid, their objects stand apart on the
ground and stay in view of the real camera poses, their materials are physically plausible; a
seed gives the same bytes in any process, pins hold and move nothing else, a bad pin is one line;
the asset bounds the sampler relies on are the built meshes' and drawn scenes' meshes do not
intersect; the smoke's optical depth statistic and its calibration; tiny drawn scenes generate
end to end and validate; a random set runs on the Dask scheduler and resumes."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats
from scipy.spatial.transform import Rotation

from generator import benchmark_cli, cli
from generator.api import random_spec
from generator.assets import load_manifest
from generator.errors import SpecError
from generator.footprints import local_bounds
from generator.optical_depth import mean_optical_depth, scale_for_target
from generator.rig import rgb_frames, timeline
from generator.sampler import GAP_M, KINDS, _sizes, draw_spec
from generator.sampler_axes import AXIS_BY_NAME, parse_pins
from generator.spec import parse_spec

REPO = Path(__file__).resolve().parents[1]
SEEDS = range(200)
TINY = ["--frames", "4", "--resolution", "32x24", "--thermal-resolution", "16x12", "--samples", "2",
        "--sim-resolution", "12"]
WARM = {"person": (305.0, 310.0), "engine": (320.0, 380.0), "heater": (320.0, 380.0), "grill": (320.0, 380.0),
        "generator": (320.0, 380.0)}


@pytest.fixture(scope="module")
def manifest():
    return load_manifest()


@pytest.fixture(scope="module")
def drawn(manifest) -> dict[int, dict]:
    return {seed: draw_spec(seed, manifest=manifest) for seed in SEEDS}


def _corners(obj: dict, manifest) -> np.ndarray:
    """The object's bounds placed as Blender places it (XYZ Euler, then scale), (8, 3)."""
    b = local_bounds(manifest.assets[obj["asset"]], obj["params"])
    local = np.array([[x, y, z] for x in (b.lo[0], b.hi[0]) for y in (b.lo[1], b.hi[1]) for z in (b.lo[2], b.hi[2])])
    rotation = Rotation.from_euler("xyz", obj["rotation_deg"], degrees=True).as_matrix()
    return (local * np.asarray(obj["scale"])) @ rotation.T + np.asarray(obj["location"])


def _ground_outline(corners: np.ndarray, per_edge: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """The convex ground polygon under an upright object (its 4 bottom corners in order) and
    points along its edges."""
    bottom = corners[corners[:, 2] <= corners[:, 2].min() + 1e-9][:, :2]
    centre = bottom.mean(axis=0)
    polygon = bottom[np.argsort(np.arctan2(*(bottom - centre).T[::-1]))]
    t = np.linspace(0.0, 1.0, per_edge, endpoint=False)[:, None]
    edges = np.concatenate([a + t * (b - a) for a, b in zip(polygon, np.roll(polygon, -1, axis=0))])
    return polygon, edges


def _inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Points strictly inside a convex counter-clockwise polygon (cross products)."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    cross = ((b - a)[None, :, 0] * (points[:, None, 1] - a[None, :, 1])
             - (b - a)[None, :, 1] * (points[:, None, 0] - a[None, :, 0]))
    return np.all(cross > 0, axis=1)


def _in_view(corners: np.ndarray, c2w: np.ndarray, width: int, height: int, fov_deg: float) -> bool:
    """Every corner projects inside the image of a pinhole camera (OpenGL axes) in front of it."""
    cam = (np.linalg.inv(c2w) @ np.c_[corners, np.ones(len(corners))].T)[:3].T
    if np.any(cam[:, 2] >= 0):
        return False
    f = width / (2 * math.tan(math.radians(fov_deg) / 2))
    u = width / 2 + f * cam[:, 0] / -cam[:, 2]
    v = height / 2 - f * cam[:, 1] / -cam[:, 2]
    return bool(np.all((u >= 0) & (u <= width) & (v >= 0) & (v <= height)))


def test_two_hundred_drawn_specs_are_valid_apart_on_the_ground_and_in_view(drawn: dict, manifest) -> None:
    worst_share, closest = 1.0, np.inf
    for seed, data in drawn.items():
        spec = parse_spec(data, f"seed {seed}")
        objects = [o for o in data["objects"] if o["asset"] != "ground_plane"]
        assert 3 <= len(objects) <= 8 and 1 <= len(spec.sources) <= 3, seed
        corners = {o["name"]: _corners(o, manifest) for o in objects}
        outlines = {name: _ground_outline(c) for name, c in corners.items()}
        for name, c in corners.items():
            assert abs(c[:, 2].min()) < 1e-3, f"seed {seed}: {name} does not stand on the ground"
        names = sorted(outlines)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                (poly_a, edge_a), (poly_b, edge_b) = outlines[a], outlines[b]
                assert not _inside(edge_a, poly_b).any() and not _inside(edge_b, poly_a).any(), (seed, a, b)
                gap = np.linalg.norm(edge_a[:, None] - edge_b[None], axis=2).min()
                closest = min(closest, gap)
        rgb = spec.rig.rgb
        frames = rgb_frames(spec, timeline(spec))
        lo = np.asarray(spec.sim.center) - np.asarray(spec.sim.size) / 2
        hi = np.asarray(spec.sim.center) + np.asarray(spec.sim.size) / 2
        for f in frames:
            assert not np.all((f.c2w[:3, 3] > lo) & (f.c2w[:3, 3] < hi)), f"seed {seed}: camera in the smoke domain"
        for name, c in corners.items():
            share = np.mean([_in_view(c, f.c2w, rgb.width, rgb.height, rgb.fov_deg) for f in frames])
            assert share >= 0.8, f"seed {seed}: {name} in view in {share:.0%} of the RGB frames"
            worst_share = min(worst_share, share)
    assert closest >= GAP_M - 0.01  # sampled edges: within a centimetre of the exact gap
    print(f"closest objects {closest:.3f} m apart; least in-view share {worst_share:.2f}")


def test_drawn_materials_and_axes_are_physically_plausible(drawn: dict) -> None:
    targets, fire, kinds, particles = [], 0, set(), set()
    for seed, data in drawn.items():
        ambient = data["lights"]["ambient_temperature_k"]
        assert 278.0 <= ambient <= 308.0 and data["lights"]["sky_temperature_k"] < ambient - 20
        for o in data["objects"]:
            mat = data["materials"][o["material"]]
            role = o["name"].rsplit("_", 1)[0]
            lo, hi = WARM.get(role, (ambient - 10.0, ambient + 12.0))
            assert lo <= mat["temperature_k"] <= hi, (seed, o["name"], mat["temperature_k"], ambient)
            assert 0.2 <= mat["emissivity"] <= 0.99
        assert any(o["name"].rsplit("_", 1)[0] in WARM for o in data["objects"]), f"seed {seed}: no warm object"
        wind = np.linalg.norm(data["sim"]["wind"])
        rgb, thermal = data["rig"]["rgb"], data["rig"]["thermal"]
        assert wind <= 3.0 + 1e-3 and data["sim"]["wind"][2] == 0.0
        assert 0.3 - 1 / rgb["width"] <= thermal["width"] / rgb["width"] <= 0.5 + 1 / rgb["width"]
        assert 0.0 <= thermal["time_offset_s"] <= 0.1
        assert 0.03 - 1e-3 <= np.linalg.norm(thermal["baseline_m"]) <= 0.15 + 1e-3
        assert (rgb["width"], rgb["height"], data["frames"]) == (160, 120, 24)
        targets.append(data["smoke"]["optical_depth"])
        fire += any(s["type"] != "smoke" for s in data["sources"])
        for s in data["sources"]:
            assert (900 <= s["temperature_k"] <= 1300) if s["type"] != "smoke" else (320 <= s["temperature_k"] <= 420)
        kinds.add(data["rig"]["trajectory"]["kind"])
        particles.add(data["smoke"]["particles"])
    logs = np.log(targets)
    assert min(targets) >= 0.1 and max(targets) <= 3.5
    # log-uniform over [0.1, 3.5]: the logs are uniform (Kolmogorov-Smirnov)
    assert stats.kstest(logs, stats.uniform(math.log(0.1), math.log(35.0)).cdf).pvalue > 0.01
    assert 0.2 <= fire / len(drawn) <= 0.4 and kinds == {"orbit", "flyover"} and particles == {"soot", "organic_smoke"}


def test_same_seed_gives_the_same_bytes_in_any_process_and_seeds_differ(drawn: dict) -> None:
    text = yaml.safe_dump(draw_spec(17), sort_keys=False)
    assert text == yaml.safe_dump(draw_spec(17), sort_keys=False)
    result = subprocess.run([sys.executable, "-m", "generator.cli", "--random", "17", "--print-spec"], cwd=REPO,
                            capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONHASHSEED": "7"})
    assert result.returncode == 0, result.stderr
    assert result.stdout == random_spec(17)[0].to_yaml() == text
    texts = {yaml.safe_dump(d, sort_keys=False) for d in drawn.values()}
    assert len(texts) == len(drawn)


def test_pins_hold_and_move_only_their_axis(manifest) -> None:
    pins = parse_pins(["smoke.particles=soot", "fire=false", "optical_depth=0.5:2", "objects.count=5",
                       "rig.trajectory=flyover", "sim.wind=0", "thermal.scale=0.5"])
    axis = AXIS_BY_NAME["smoke.optical_depth"]
    for seed in range(30):
        d = draw_spec(seed, pins, manifest)
        assert d["smoke"]["particles"] == "soot" and all(s["type"] == "smoke" for s in d["sources"])
        assert 0.5 <= d["smoke"]["optical_depth"] <= 2.0 and len(d["objects"]) == 6
        assert d["rig"]["trajectory"]["kind"] == "flyover" and d["sim"]["wind"] == [0.0, 0.0, 0.0]
        assert d["rig"]["thermal"]["width"] == 80
        # A range maps the same uniform number: the pinned value sits where the free one does.
        free = draw_spec(seed, manifest=manifest)
        u_free = math.log(free["smoke"]["optical_depth"] / 0.1) / math.log(axis.default[1] / axis.default[0])
        u_pinned = math.log(d["smoke"]["optical_depth"] / 0.5) / math.log(4.0)
        assert u_pinned == pytest.approx(u_free, abs=1e-3)
        # Pinning the particles changes the particles and nothing else.
        soot = draw_spec(seed, parse_pins(["particles=soot"]), manifest)
        soot["smoke"]["particles"] = free["smoke"]["particles"]
        assert soot == free


@pytest.mark.parametrize("item, needle", [
    ("smok=1", "--set: smok: unknown axis; the axes are objects.count"),
    ("fire=maybe", "--set: fire: must be true or false, got 'maybe'"),
    ("optical_depth=2:0.5", "--set: optical_depth: range '2:0.5' runs backwards"),
    ("objects.count=2.5", "--set: objects.count: must be an integer from 1 to 8"),
    ("objects.count=9", "--set: objects.count: must be an integer from 1 to 8"),
    ("smoke.particles=wood", "--set: smoke.particles: must be one of organic_smoke, soot"),
    ("sim.wind=-1", "--set: sim.wind: must be a number from 0 to 10"),
    ("optical_depth", "--set: expected KEY=VALUE"),
])
def test_a_bad_pin_is_one_clear_line(tmp_path: Path, item: str, needle: str, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "scene"
    for main, args in ((cli.main, ["--random", "3"]), (benchmark_cli.main, ["--random", "2"])):
        assert main([*args, "--set", item, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert needle in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()


def test_a_bad_pin_is_one_line_across_the_process_boundary(tmp_path: Path) -> None:
    for module, prog, count in (("generator.cli", "generate-scene", "3"),
                                ("generator.benchmark_cli", "generate-benchmark", "2")):
        result = subprocess.run([sys.executable, "-m", module, "--random", count, "--set", "fire=maybe", "--out",
                                 str(tmp_path / "x")], cwd=REPO, capture_output=True, text=True, timeout=120)
        assert result.returncode == 2 and result.stderr.strip().splitlines() == [
            f"{prog}: error: --set: fire: must be true or false, got 'maybe'"], result.stderr


def test_optical_depth_statistic_and_its_calibration() -> None:
    rng = np.random.default_rng(0)
    # A uniform slab: every pixel's optical depth, exactly.
    assert mean_optical_depth(np.full((2, 8, 8), -math.expm1(-1.7))) == pytest.approx(1.7, rel=1e-9)
    # A plume over clear sky: continuous and strictly increasing in the scale, scale recovered.
    tau = np.where(rng.random((6, 24, 32)) < 0.3, rng.lognormal(0.0, 1.0, (6, 24, 32)), 0.0)
    alphas = -np.expm1(-tau)
    scales = np.geomspace(1e-3, 1e3, 400)
    values = np.array([mean_optical_depth(alphas, k) for k in scales])
    assert np.all(np.diff(values) > 0) and np.max(np.diff(np.log(values))) < 0.1
    for k in (0.05, 1.0, 2.7, 40.0):
        assert scale_for_target(alphas, mean_optical_depth(alphas, k)) == pytest.approx(k, rel=1e-6)
    # Extremes: no smoke is 0, opaque smoke is finite, nothing is NaN.
    assert mean_optical_depth(np.zeros((3, 4, 4))) == 0.0
    assert math.isfinite(mean_optical_depth(np.ones((3, 4, 4)))) and math.isfinite(mean_optical_depth(alphas, 1e6))


def test_optical_depth_is_an_optional_spec_field_that_leaves_older_digests_alone() -> None:
    from generator.presets import load_preset

    demo = load_preset("demo")
    data = demo.to_dict()
    assert demo.smoke.optical_depth is None and "optical_depth" not in data["smoke"]
    data["smoke"]["optical_depth"] = 1.25
    spec = parse_spec(data, "scene.yaml")
    assert spec.smoke.optical_depth == 1.25 and spec.sha256() != demo.sha256()
    assert parse_spec(yaml.safe_load(spec.to_yaml()), "scene.yaml") == spec
    for bad in (0, -1.0, "thick", 51.0):
        data["smoke"]["optical_depth"] = bad
        with pytest.raises(SpecError, match="scene.yaml: smoke.optical_depth: must be"):
            parse_spec(data, "scene.yaml")


def _blender_script(name: str, tmp_path: Path, *args: str) -> dict:
    out = tmp_path / "result.json"
    result = subprocess.run([sys.executable, str(REPO / "tests" / "blender_scripts" / name), str(out), str(tmp_path),
                             *args], cwd=REPO, capture_output=True, text=True, timeout=600,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    assert result.returncode == 0 and out.exists(), result.stderr[-3000:]
    return json.loads(out.read_text())


@pytest.mark.blender
def test_asset_bounds_are_the_built_meshes_and_drawn_scenes_do_not_intersect(tmp_path: Path, manifest) -> None:
    rng = np.random.default_rng(1)
    assets = []
    for kind in {k.asset + k.sizes: k for k in KINDS}.values():
        for params in ([_sizes(rng, kind.sizes) for _ in range(3)] if kind.sizes else [{}]):
            assets.append([kind.label, kind.asset, params])
    control = {"name": "control", "objects": [
        {"name": "a", "asset": "box", "params": {"dimensions": [1.0, 1.0, 1.0]}, "location": [0.0, 0.0, 0.0],
         "rotation_deg": [0.0, 0.0, 0.0], "scale": [1.0, 1.0, 1.0]},
        {"name": "b", "asset": "box", "params": {"dimensions": [1.0, 1.0, 1.0]}, "location": [0.6, 0.3, 0.0],
         "rotation_deg": [0.0, 0.0, 30.0], "scale": [1.0, 1.0, 1.0]}]}
    request = tmp_path / "request.json"
    request.write_text(json.dumps({"assets": assets, "scenes": [draw_spec(seed) for seed in range(6)] + [control]}))
    report = _blender_script("sampler_meshes.py", tmp_path, str(request))
    for built in report["bounds"]:
        ours = local_bounds(manifest.assets[built["asset"]], built["params"])
        assert np.allclose(ours.lo, built["lo"], atol=2e-3) and np.allclose(ours.hi, built["hi"], atol=2e-3), built
    *scenes, check = report["scenes"]
    assert check["overlaps"] == [["a", "b"]]  # the overlap test sees an intersection when there is one
    for scene in scenes:
        assert scene["objects"] >= 3 and scene["overlaps"] == [], scene
        assert all(abs(z) < 2e-3 for z in scene["lowest"].values()), scene


@pytest.mark.blender
def test_the_opacity_pass_carries_each_rays_transmittance(tmp_path: Path) -> None:
    images = _blender_script("alpha_materials.py", tmp_path)
    assert images["pass_material"] == "smoke.rgb.extinction"
    reference, four, one = (np.asarray(images[k]) for k in ("scattering_1024", "extinction_4", "extinction_1"))
    smoke = reference > 0.02
    assert smoke.sum() > 50
    # Same expected opacity as the scattering material, at 1/256 of its samples (what is left
    # per pixel is where in the pixel the few samples fall: 0.05 RMSE at 4 samples, 0.01 over
    # 2x2 blocks) ...
    assert four.mean() == pytest.approx(reference.mean(), rel=0.03)
    assert one.mean() == pytest.approx(reference.mean(), rel=0.03)
    assert np.corrcoef(four[smoke], reference[smoke])[0, 1] > 0.97

    def blocks(a: np.ndarray) -> np.ndarray:
        return a.reshape(a.shape[0] // 2, 2, a.shape[1] // 2, 2).mean(axis=(1, 3))

    assert np.sqrt(np.mean((blocks(four) - blocks(reference)) ** 2)) < 0.03
    # ... and not quantised in steps of 1/samples: most smoke pixels of the 1-sample image differ.
    assert len(np.unique(np.round(one[smoke], 4))) > 0.5 * smoke.sum()
    print(f"mean opacity: scattering x1024 {reference.mean():.4f}, extinction x4 {four.mean():.4f}, "
          f"x1 {one.mean():.4f}")


@pytest.mark.blender
@pytest.mark.slow
def test_three_tiny_random_scenes_generate_and_validate(tmp_path: Path) -> None:
    cases = {3: ["--set", "fire=true", "--set", "smoke.particles=soot"],
             4: ["--set", "rig.trajectory=flyover", "--set", "fire=false"], 5: []}
    for seed, pins in cases.items():
        out = tmp_path / f"random_{seed}"
        args = [sys.executable, "-m", "generator.cli", "--random", str(seed), *pins, *TINY]
        result = subprocess.run([*args, "--out", str(out), "--quiet"], cwd=REPO, capture_output=True, text=True,
                                timeout=600)
        assert result.returncode == 0, result.stderr[-3000:]
        valid = subprocess.run([sys.executable, "-m", "generator.cli", "--validate", str(out)], cwd=REPO,
                               capture_output=True, text=True, timeout=300)
        assert valid.returncode == 0 and "valid" in valid.stdout, valid.stderr
        printed = subprocess.run([*args, "--print-spec"], cwd=REPO, capture_output=True, text=True, timeout=120)
        scene_yaml = (out / "scene.yaml").read_text()
        assert scene_yaml == printed.stdout  # the drawn spec, byte for byte
        meta = json.loads((out / "dataset.json").read_text())
        assert parse_spec(yaml.safe_load(scene_yaml), "scene.yaml").sha256() == meta["spec_sha256"]
        depth = meta["smoke"]["optical_depth"]
        assert depth["target"] == yaml.safe_load(scene_yaml)["smoke"]["optical_depth"]
        assert depth["achieved"] == pytest.approx(depth["target"], rel=0.25), depth
        if seed == 3:
            assert meta["smoke"]["fire"] and meta["smoke"]["particles"] == "soot"
        print(seed, depth)


def test_a_random_set_runs_on_dask_and_skips_finished_scenes(tmp_path: Path) -> None:
    for seed, total in ((40, 101.0), (41, 77.0)):
        spec, _ = random_spec(seed)
        folder = tmp_path / f"random_{seed}"
        folder.mkdir()
        (folder / "dataset.json").write_text(json.dumps({
            "spec_sha256": spec.sha256(), "timings_s": {"total": total}, "stats": {},
            "smoke": {"optical_depth": {"target": spec.smoke.optical_depth, "achieved": 0.9}}}))
    code = benchmark_cli.main(["--random", "2", "--seed-base", "40", "--out", str(tmp_path), "--workers", "2"])
    assert code == 0
    summary = json.loads((tmp_path / "benchmark.json").read_text())
    assert [(r["scene"], r["status"], r["seconds"]) for r in summary["scenes"]] == [
        ("random_40", "reused", 101.0), ("random_41", "reused", 77.0)]
    assert "dask scheduler" in summary["scheduler"] and summary["workers"] == 2
    assert summary["threads_per_worker"] == max(1, (os.cpu_count() or 1) // 2) and summary["provenance"]["commit"]
    table = (tmp_path / "benchmark.md").read_text()
    assert "| random_40 | reused | 101 | n/a |" in table and "| random_41 | reused | 77 | n/a |" in table
    assert all(r["load_average_before"] is None for r in summary["scenes"])  # today's load is not the scene's


def test_a_reused_scene_keeps_the_load_of_the_call_that_generated_it(tmp_path: Path) -> None:
    for seed in (40, 41):
        spec, _ = random_spec(seed)
        (tmp_path / f"random_{seed}").mkdir()
        (tmp_path / f"random_{seed}" / "dataset.json").write_text(json.dumps({
            "spec_sha256": spec.sha256(), "timings_s": {"total": 60.0}, "stats": {}, "code_sha256": "c0de",
            "smoke": {"optical_depth": {"target": spec.smoke.optical_depth, "achieved": 0.9}}}))
    earlier = {"random_40": {"status": "generated", "load_average_before": [3.3, 2.0, 1.0]},
               "random_41": {"status": "reused", "load_average_before": [0.6, 0.5, 0.4]}}  # an older file's guess
    (tmp_path / "benchmark.json").write_text(json.dumps({"scenes": [
        {"scene": k, "code_sha256": "c0de", "optical_depth_achieved": 0.9, **v} for k, v in earlier.items()]}))
    args = ["--random", "2", "--seed-base", "40", "--out", str(tmp_path), "--workers", "1"]
    for _ in range(2):  # the second call reads the first's records: the load survives being reused twice
        assert benchmark_cli.main(args) == 0
        scenes = {r["scene"]: r for r in json.loads((tmp_path / "benchmark.json").read_text())["scenes"]}
        assert scenes["random_40"]["load_average_before"] == [3.3, 2.0, 1.0]
        assert scenes["random_40"]["load_from_earlier_call"] is True
        assert scenes["random_41"]["load_average_before"] is None
        table = (tmp_path / "benchmark.md").read_text()
        assert "| random_40 | reused | 60 | 3.3 |" in table and "| random_41 | reused | 60 | n/a |" in table
