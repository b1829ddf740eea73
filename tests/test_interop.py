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
from smokeseer.cameras import c2w_gl_to_viewmat
from smokeseer.data import load_scene
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
    ref = load_scene(source)
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
