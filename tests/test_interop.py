"""convert-dataset: the official SmokeSeer layouts and nerfstudio, checked by an independent
reader that follows the official code's rules, and read back through our own loader."""
from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from interop.convert import convert, main
from interop.resample import warp_to_intrinsics
from scenes.cameras import c2w_gl_to_viewmat
from scenes.load import load_scene
from tests.test_smokeseer_data import write_splat_dataset

N_RGB, N_THERMAL = 17, 9


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_splat_dataset(tmp_path_factory.mktemp("interop") / "src", n_rgb=N_RGB, n_thermal=N_THERMAL,
                               rgb_size=(16, 12), thermal_size=(12, 8))


@pytest.fixture(scope="module")
def outputs(source: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("converted")
    out = {}
    for target, name in (("smokeseer-blender", "blender"), ("smokeseer-colmap", "colmap"),
                         ("nerfstudio", "nerfstudio")):
        convert(source, target, root / name)
        out[name] = root / name
    return out


# ----------------------------------------------------------------------------- independent readers

def official_blender_frames(root: Path, transforms: str) -> list[dict]:
    """The official reader's rules, restated: file_path + '.png', the last two path parts kept,
    the _gt image found by splitting at the first dot, RGBA opened."""
    doc = json.loads((root / transforms).read_text())
    assert isinstance(doc["camera_angle_x"], float)
    frames = []
    for fr in doc["frames"]:
        cam_name = "/".join(str(root / (fr["file_path"] + ".png")).split("/")[-2:])
        gt_name = cam_name.split(".")[0] + "_gt." + cam_name.split(".")[1]
        with Image.open(root / cam_name) as im:
            rgba = np.asarray(im.convert("RGBA"))
            mode = im.mode
        gt = root / gt_name
        frames.append({"name": Path(cam_name).stem, "time": fr["frame"], "rgba": rgba, "mode": mode,
                       "gt": gt.exists(), "c2w": np.asarray(fr["transform_matrix"]),
                       "fovx": doc["camera_angle_x"]})
    return frames


def read_colmap_model(sparse: Path) -> tuple[dict, list]:
    """Hand-unpacked cameras.bin / images.bin (COLMAP's documented record layout)."""
    data = (sparse / "cameras.bin").read_bytes()
    (n,) = struct.unpack_from("<Q", data, 0)
    pos, cams = 8, {}
    for _ in range(n):
        cid, model, w, h = struct.unpack_from("<iiQQ", data, pos)
        pos += 24
        nparams = {0: 3, 1: 4}[model]
        cams[cid] = (model, w, h, struct.unpack_from("<" + "d" * nparams, data, pos))
        pos += 8 * nparams
    data = (sparse / "images.bin").read_bytes()
    (n,) = struct.unpack_from("<Q", data, 0)
    pos, images = 8, []
    for _ in range(n):
        iid, qw, qx, qy, qz, tx, ty, tz, cid = struct.unpack_from("<idddddddi", data, pos)
        pos += 64
        end = data.index(b"\0", pos)
        name = data[pos:end].decode()
        pos = end + 1
        (npts,) = struct.unpack_from("<Q", data, pos)
        pos += 8 + 24 * npts
        images.append((name, cid, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz])))
    assert pos == len(data)
    return cams, images


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


# ----------------------------------------------------------------------------- the layouts

def test_blender_layout_as_the_official_reader_sees_it(source: Path, outputs: dict[str, Path]) -> None:
    ref = load_scene(source)
    root = outputs["blender"]
    assert "." not in root.name
    train = official_blender_frames(root, "transforms_train.json")
    test = official_blender_frames(root, "transforms_test.json")
    rgb = sorted(train + test, key=lambda f: f["time"])
    assert len(rgb) == N_RGB and all(f["gt"] and f["mode"] == "RGBA" for f in rgb)
    assert sorted(f["name"] for f in test) == [rgb[i]["name"] for i in range(0, N_RGB, 8)]
    thermal = official_blender_frames(root, "transforms_thermaltrain.json") + \
        official_blender_frames(root, "transforms_thermaltest.json")
    assert len(thermal) == N_THERMAL and all("thermal" in f["name"] for f in thermal)
    for got, want in zip(rgb, ref.rgb.frames):
        np.testing.assert_allclose(c2w_gl_to_viewmat(got["c2w"]), want.viewmat, atol=1e-9)
        assert got["time"] == pytest.approx(want.time, abs=1e-12)
        assert got["fovx"] == pytest.approx(2 * math.atan(0.5 * want.width / want.K[0, 0]), rel=1e-12)
        assert np.all(got["rgba"][..., 3] == 255)
    np.testing.assert_array_equal(rgb[3]["rgba"][..., :3],
                                  np.asarray(Image.open(source / "rgb" / "smoky" / "0003.png")))


def test_colmap_layout_as_the_official_reader_sees_it(source: Path, outputs: dict[str, Path]) -> None:
    ref = load_scene(source)
    root = outputs["colmap"]
    cams, images = read_colmap_model(root / "sparse" / "0")
    assert len(images) == N_RGB + N_THERMAL
    for model, w, h, params in cams.values():
        assert model == 1 and params[2] == w / 2 and params[3] == h / 2
    names = [n for n, *_ in images]
    assert all(("rgb" in n) != ("thermal" in n) and "gt" not in n and any(c.isdigit() for c in n) for n in names)
    numbers = {n: int("".join(filter(str.isdigit, n))) for n in names}
    rgb = sorted((i for i in images if "rgb" in i[0]), key=lambda i: i[0])
    thermal = sorted((i for i in images if "thermal" in i[0]), key=lambda i: i[0])
    assert len({cid for _, cid, *_ in rgb}) == 1 and len({cid for _, cid, *_ in thermal}) == 1
    # Sorted by name is time order, and frame numbers are one clock for both modalities.
    lo, hi = min(numbers.values()), max(numbers.values())
    span = max(f.timestamp_s for m in (ref.rgb, ref.thermal) for f in m.frames)
    for (name, _, q, t), want in zip(rgb + thermal, ref.rgb.frames + ref.thermal.frames):
        np.testing.assert_allclose(_quat_matrix(q), want.viewmat[:3, :3], atol=1e-9)
        np.testing.assert_allclose(t, want.viewmat[:3, 3], atol=1e-9)
        assert (numbers[name] - lo) / (hi - lo) * span == pytest.approx(want.timestamp_s, abs=1e-5)
        with Image.open(root / "images" / name) as im:
            assert im.mode == "RGB"
        assert (root / "images_mask" / name).is_file()
        if "rgb" in name:
            assert (root / "images" / name.replace(".png", "_gt.png")).is_file()
    assert (root / "sparse" / "0" / "points3D.bin").stat().st_size > 8


def test_nerfstudio_transforms_per_modality(source: Path, outputs: dict[str, Path]) -> None:
    ref = load_scene(source)
    for modality, mod in (("rgb", ref.rgb), ("thermal", ref.thermal)):
        doc = json.loads((outputs["nerfstudio"] / modality / "transforms.json").read_text())
        assert len(doc["frames"]) == len(mod.frames)
        assert len(doc["train_filenames"]) + len(doc["test_filenames"]) == len(mod.frames)
        for fr, want in zip(doc["frames"], mod.frames):
            assert (outputs["nerfstudio"] / modality / fr["file_path"]).is_file()
            np.testing.assert_allclose(c2w_gl_to_viewmat(np.asarray(fr["transform_matrix"])), want.viewmat, atol=1e-9)
            assert fr["fl_x"] == pytest.approx(want.K[0, 0])


@pytest.mark.parametrize("layout", ["blender", "colmap"])
def test_round_trip_through_our_loader(source: Path, outputs: dict[str, Path], layout: str) -> None:
    ref = load_scene(source, all_ground_truth=True)
    back = load_scene(outputs[layout])
    assert back.meta["layout"] == f"smokeseer-{layout}" and back.notes == []
    assert (back.smoke_present, back.smoke_static) == (ref.smoke_present, ref.smoke_static)
    for name in ("rgb", "thermal"):
        a, b = getattr(ref, name), getattr(back, name)
        assert len(a.frames) == len(b.frames)
        for x, y in zip(a.frames, b.frames):
            np.testing.assert_allclose(y.viewmat, x.viewmat, atol=1e-9)
            np.testing.assert_allclose(y.K, x.K, atol=1e-12)
            assert y.time == pytest.approx(x.time, abs=1e-5)
            assert y.timestamp_s == pytest.approx(x.timestamp_s, abs=1e-6)
        # RGB is 8-bit in and out; thermal goes through 8 bits, so within one step after renormalising.
        np.testing.assert_allclose(b.images, a.images, atol=1e-7 if name == "rgb" else 2.5 / 255)
    np.testing.assert_array_equal(back.rgb.clean, ref.rgb.clean)
    np.testing.assert_array_equal(back.rgb.masks, ref.rgb.masks)
    assert [f.split for f in back.rgb.frames] == ["test" if i % 8 == 0 else "train" for i in range(N_RGB)]


def test_source_split_kept_in_blender_layout(source: Path, tmp_path: Path) -> None:
    convert(source, "smokeseer-blender", tmp_path / "kept", split="source")
    ref, back = load_scene(source), load_scene(tmp_path / "kept")
    assert [f.split for f in back.rgb.frames] == [f.split for f in ref.rgb.frames]


def test_resampling_to_a_centred_principal_point() -> None:
    """An image defined analytically on camera rays keeps its value on every ray after the warp."""
    h, w = 40, 60
    k_src = np.array([[50.0, 0, 33.7], [0, 47.0, 18.2], [0, 0, 1]])
    k_dst = np.array([[50.0, 0, 30.0], [0, 50.0, 20.0], [0, 0, 1]])

    def on_rays(k: np.ndarray) -> np.ndarray:
        v, u = np.mgrid[0:h, 0:w] + 0.5
        x, y = (u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1]
        return 0.5 + 0.3 * np.sin(3 * x) * np.cos(2 * y)

    warped, lost = warp_to_intrinsics(on_rays(k_src), k_src, k_dst)
    inside = warped > 0
    assert 0 < lost < 0.2 and inside.mean() == pytest.approx(1 - lost)
    assert np.abs(warped - on_rays(k_dst))[inside].max() < 2e-3


def test_bad_requests_leave_nothing_behind(source: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main([str(source), "--to", "smokeseer-blender", "--out", str(tmp_path / "with.dot")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "dot" in err[0]
    assert main([str(tmp_path / "nowhere"), "--to", "smokeseer-colmap", "--out", str(tmp_path / "x")]) == 2
    assert "not a directory" in capsys.readouterr().err
    assert main([str(source), "--to", "smokeseer-colmap", "--split", "source", "--out", str(tmp_path / "y")]) == 2
    assert "--split source" in capsys.readouterr().err
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "dataset.json").write_text((source / "dataset.json").read_text())
    (broken / "transforms_rgb.json").write_text("{")
    assert main([str(broken), "--to", "nerfstudio", "--out", str(tmp_path / "z")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken"]


def test_official_layouts_without_our_sidecar(outputs: dict[str, Path], tmp_path: Path) -> None:
    """Data prepared for the official code by someone else: no smokeseer_interop.json. Times
    follow the official reader, and what was assumed is said."""
    import shutil

    for layout in ("blender", "colmap"):
        bare = tmp_path / layout
        shutil.copytree(outputs[layout], bare)
        (bare / "smokeseer_interop.json").unlink()
        scene = load_scene(bare)
        assert scene.smoke_present and not scene.smoke_static
        assert any("smokeseer_interop.json" in n for n in scene.notes)
        times = [f.time for f in scene.rgb.frames + scene.thermal.frames]
        assert min(times) == pytest.approx(0.0) and max(times) <= 1.0 + 1e-12
    images = tmp_path / "colmap" / "images"
    (images / "rgb_0000000000.png").rename(images / "rgb_first.png")
    data = (tmp_path / "colmap" / "sparse" / "0" / "images.bin").read_bytes()
    (tmp_path / "colmap" / "sparse" / "0" / "images.bin").write_bytes(
        data.replace(b"rgb_0000000000.png\0", b"rgb_first.png\0"))
    with pytest.raises(Exception, match="has no digits"):
        load_scene(tmp_path / "colmap")


# ----------------------------------------------------------------------------- depth (images_depth)

def official_inverse_depth(root: Path, name: str) -> tuple[np.ndarray, bool]:
    """The official reader's depth, restated: images_depth/STEM.png read unchanged, divided by
    2^16, then ``· scale + offset`` from sparse/0/depth_params.json; an image whose scale lies
    outside [0.2, 5] × the median positive scale is not trusted."""
    params = json.loads((root / "sparse" / "0" / "depth_params.json").read_text())
    scales = np.array([p["scale"] for p in params.values()])
    med = np.median(scales[scales > 0])
    stem = name[: -len(name.split(".")[-1]) - 1]
    with Image.open(root / "images_depth" / f"{stem}.png") as im:
        assert im.mode == "I;16"
        raw = np.asarray(im).astype(np.float64) / 2 ** 16
    p = params[stem]
    reliable = 0.2 * med <= p["scale"] <= 5 * med
    return np.maximum(raw * p["scale"] + p["offset"], 0.0), reliable


def depth_tolerance(depths: list[np.ndarray]) -> float:
    """Relative error allowed: half a 16-bit step of inverse depth when the top code is the
    nearest surface, d_max / (2 · 65535 · d_min), plus float32 rounding."""
    d = np.concatenate([x[x > 0] for x in depths])
    return float(d.max() / (2 * 65535 * d.min())) + 1e-6


def check_official_depth(src: Path, root: Path) -> None:
    ref = load_scene(src, all_ground_truth=True)
    _, images = read_colmap_model(root / "sparse" / "0")
    truth = {}
    for mod in (ref.rgb, ref.thermal):
        names = sorted(n for n, *_ in images if mod.name in n)
        truth.update(zip(names, mod.depth))
    assert len(truth) == len(images)
    tol = depth_tolerance(list(truth.values()))
    for name, depth in truth.items():
        inv, reliable = official_inverse_depth(root, name)
        assert reliable
        hit = depth > 0
        np.testing.assert_array_equal(inv > 0, hit)
        assert np.all(np.abs(1.0 / inv[hit] - depth[hit]) <= tol * depth[hit]), name


def test_colmap_depth_as_the_official_reader_sees_it(source: Path, outputs: dict[str, Path]) -> None:
    check_official_depth(source, outputs["colmap"])
    sidecar = json.loads((outputs["colmap"] / "smokeseer_interop.json").read_text())
    assert sidecar["images_depth"] == "ground-truth"
    assert any("images_depth" in n and "ground-truth" in n for n in sidecar["notes"])


def test_colmap_depth_recovers_the_demo_depth(demo_dataset: Path, tmp_path: Path) -> None:
    """The real generator's planar depth (a range of depths, sky at 0) comes back through the
    official decoding within the quantisation bound."""
    convert(demo_dataset, "smokeseer-colmap", tmp_path / "demo")
    check_official_depth(demo_dataset, tmp_path / "demo")
    back, ref = load_scene(tmp_path / "demo"), load_scene(demo_dataset, all_ground_truth=True)
    tol = depth_tolerance([ref.rgb.depth, ref.thermal.depth])
    for a, b in ((ref.rgb, back.rgb), (ref.thermal, back.thermal)):
        hit = a.depth > 0
        assert np.all(np.abs(b.depth[hit] - a.depth[hit]) <= tol * a.depth[hit] + 1e-6)


def test_depth_round_trip_and_its_use_as_a_prior(source: Path, outputs: dict[str, Path]) -> None:
    import torch

    from smokeseer.api import depth_prior_maps
    from smokeseer.config import make_config
    from smokeseer.train.plan import plan_stage3

    def depth_file_notes(cfg, scene):
        return [n for n in plan_stage3(cfg, scene).notes if n.startswith("images_depth:")]

    ref, back = load_scene(source, all_ground_truth=True), load_scene(outputs["colmap"])
    tol = depth_tolerance([ref.rgb.depth, ref.thermal.depth])
    for a, b in ((ref.rgb, back.rgb), (ref.thermal, back.thermal)):
        hit = a.depth > 0
        np.testing.assert_array_equal(b.inverse_depth > 0, hit)
        assert np.all(np.abs(1.0 / b.inverse_depth[hit] - a.depth[hit]) <= tol * a.depth[hit])
        np.testing.assert_allclose(b.depth, a.depth, rtol=tol, atol=1e-6)
    # Unused maps are said, per modality and why.
    default = depth_file_notes(make_config("full", "standard"), back)
    assert len(default) == 2 and all("depth_prior=files" in n for n in default)
    files = make_config("full", "standard", overrides={"depth_prior": "files"})
    thermal_camera = depth_file_notes(files, back)
    assert len(thermal_camera) == 1 and "rgb frames" in thermal_camera[0] and "thermal camera" in thermal_camera[0]
    rgb_camera = depth_file_notes(make_config("full", "quick", overrides={"depth_prior": "files"}), back)
    assert len(rgb_camera) == 1 and "thermal frames" in rgb_camera[0]
    no_depth = depth_file_notes(make_config("no-depth", "standard", overrides={"depth_prior": "files"}), back)
    assert len(no_depth) == 2 and all("no depth term" in n for n in no_depth)
    # Used: the thermal training frames' inverse depth, compared as inverse depth.
    plan = plan_stage3(files, back)
    assert (plan.depth_prior, plan.depth_camera) == ("files", "thermal")
    prior = depth_prior_maps(files, plan, None, back, torch.device("cpu"))
    idx = back.thermal.indices("train")
    assert prior.camera == "thermal" and prior.space == "disparity"
    np.testing.assert_array_equal(prior.maps.numpy(), back.thermal.inverse_depth[idx])
    with pytest.raises(ValueError, match="depth_prior: files needs depth maps for the thermal frames"):
        plan_stage3(files, load_scene(outputs["blender"]))


def test_bad_depth_files_are_named(outputs: dict[str, Path], tmp_path: Path) -> None:
    import shutil

    from contracts.errors import DatasetError

    root = tmp_path / "colmap"
    shutil.copytree(outputs["colmap"], root)
    params = root / "sparse" / "0" / "depth_params.json"
    good = params.read_text()
    params.write_text(json.dumps({"rgb_0000000000": {"scale": "big", "offset": 0}}))
    with pytest.raises(DatasetError, match=r"depth_params.json: 'rgb_0000000000'.scale: missing or not a finite"):
        load_scene(root)
    params.unlink()
    with pytest.raises(DatasetError, match=r"depth_params.json: missing file"):
        load_scene(root)
    params.write_text(good)
    first = sorted((root / "images_depth").glob("rgb_*.png"))[0]
    Image.fromarray(np.zeros((3, 3), np.uint16)).save(first)
    with pytest.raises(DatasetError, match=r"depth map is 3x3, the image is 16x12"):
        load_scene(root)
    first.unlink()
    with pytest.raises(DatasetError, match=r"missing rgb depth map \(16 of 17 frames have one\)"):
        load_scene(root)


def test_official_depth_rules_for_unscaled_and_untrusted_maps(outputs: dict[str, Path], tmp_path: Path) -> None:
    """Maps prepared by the official tools: a missing entry is used unscaled, a scale far from
    the median is not trusted; both are said."""
    import shutil

    root = tmp_path / "colmap"
    shutil.copytree(outputs["colmap"], root)
    params_path = root / "sparse" / "0" / "depth_params.json"
    params = json.loads(params_path.read_text())
    names = sorted(n for n in params if n.startswith("rgb"))
    del params[names[1]]
    params[names[2]]["scale"] *= 10
    params_path.write_text(json.dumps(params))
    ref, back = load_scene(outputs["colmap"]), load_scene(root)
    raw = np.asarray(Image.open(root / "images_depth" / f"{names[1]}.png")).astype(np.float64) / 2 ** 16
    np.testing.assert_allclose(back.rgb.inverse_depth[1], raw, rtol=1e-6)
    assert not back.rgb.inverse_depth[2].any()
    np.testing.assert_array_equal(back.rgb.inverse_depth[3], ref.rgb.inverse_depth[3])
    assert any("used unscaled" in n for n in back.notes) and any("not used" in n for n in back.notes)
