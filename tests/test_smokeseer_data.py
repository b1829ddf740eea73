"""Dataset loading, plus a bpy-free scene writer used by the other trainer tests.

``write_splat_dataset`` renders a known Gaussian scene (a textured floor and box seen by an
orbiting rig, with a drifting grey smoke cloud) through the real rasterizer into the dataset
format of docs/dataset-format.md. The smoke is composited by the same image-formation model the
method assumes, so tests can check what the method should recover without running Blender.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from contracts.errors import DatasetError
from scenes.cameras import c2w_gl_to_viewmat
from scenes.load import load_scene
from smokeseer.raster import rasterize


def _look_at_c2w_gl(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, -fwd, eye
    return m


def _surface(rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """Floor (checker texture) + a box: flat-ish Gaussians with RGB and thermal colours."""
    pts, rgb, th = [], [], []
    g = np.linspace(-1.2, 1.2, 24)
    for x in g:
        for y in g:
            pts.append([x, y, 0.0])
            c = 0.8 if (int((x + 2) * 2.5) + int((y + 2) * 2.5)) % 2 else 0.2
            rgb.append([c, 0.5 * c + 0.2, 0.3])
            th.append(0.3)
    b = np.linspace(-0.35, 0.35, 8)
    for u in b:
        for v in b:
            for face in ([u, v, 0.7], [0.35, u, 0.35 + v], [-0.35, u, 0.35 + v], [u, 0.35, 0.35 + v], [u, -0.35, 0.35 + v]):
                pts.append(face)
                rgb.append([0.2, 0.3 + 0.5 * (u + 0.35), 0.8])
                th.append(0.8)
    n = len(pts)
    return {"means": torch.tensor(pts, dtype=torch.float32),
            "scales": torch.full((n, 3), 0.06),
            "opacity": torch.full((n,), 0.95),
            "rgb": torch.tensor(rgb, dtype=torch.float32),
            "thermal": torch.tensor(th, dtype=torch.float32)[:, None]}


def _smoke(rng: np.random.Generator, t: float, n: int, opacity: float) -> dict[str, torch.Tensor]:
    base = rng.normal(0.0, 0.35, size=(n, 3)) * np.array([1.0, 1.0, 0.5])
    centre = np.array([-0.4 + 0.8 * t, 0.0, 0.6])
    return {"means": torch.tensor(base + centre, dtype=torch.float32),
            "scales": torch.full((n, 3), 0.15),
            "opacity": torch.full((n,), opacity),
            "rgb": torch.full((n, 3), 0.85),
            "thermal": torch.full((n, 1), 0.35)}


def _render(parts: list[dict[str, torch.Tensor]], key: str, opac_scale: list[float], vm: np.ndarray,
            k: np.ndarray, w: int, h: int, subset_last: bool,
            background: tuple[float, ...] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    means = torch.cat([p["means"] for p in parts])
    n = means.shape[0]
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1
    mask = None
    if subset_last:
        mask = torch.zeros(n, dtype=torch.bool)
        mask[-parts[-1]["means"].shape[0]:] = True
    out = rasterize(means, quats, torch.cat([p["scales"] for p in parts]),
                    torch.cat([p["opacity"] * s for p, s in zip(parts, opac_scale)]),
                    torch.cat([p[key] for p in parts]),
                    torch.tensor(vm, dtype=torch.float32)[None], torch.tensor(k, dtype=torch.float32)[None], w, h,
                    backgrounds=torch.tensor(background, dtype=torch.float32) if background is not None
                    else torch.zeros(parts[0][key].shape[1]), subset_mask=mask, normalize_depth=True)
    sub = out.subset_alphas[0, ..., 0].numpy() if mask is not None else None
    return out.colors[0].numpy(), out.depths[0, ..., 0].numpy(), sub


def _write_exr(path: Path, channel: str, arr: np.ndarray) -> None:
    import OpenEXR

    path.parent.mkdir(parents=True, exist_ok=True)
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {channel: arr.astype(np.float32)}).write(str(path))


def _png(path: Path, arr: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(arr).save(path)


def write_splat_dataset(path: Path, smoke: str = "moving", n_rgb: int = 12, n_thermal: int = 9,
                        rgb_size: tuple[int, int] = (48, 36), thermal_size: tuple[int, int] = (32, 24),
                        seed: int = 0, static_flag: bool = False,
                        sky: tuple[float, float, float] | None = None, shadowed: bool = True) -> Path:
    """Write a dataset in the documented format. ``smoke``: "moving", "none" or "opaque";
    ``static_flag`` only sets ``smoke.static`` in dataset.json; ``sky`` is a constant RGB
    radiance behind the scene (black when None; thermal stays black). With ``shadowed`` the RGB
    frames have the shadowed pass too: the clean frame darkened by half the smoke's opacity, a
    stand-in for a shadow."""
    rng = np.random.default_rng(seed)
    surf = _surface(rng)
    duration = 1.0
    opacity = {"moving": 0.35, "none": 0.0, "opaque": 0.99}[smoke]
    meta_passes = {"rgb": ["smoky", "clean"] + (["shadowed"] if shadowed else []) + ["depth", "smoke_alpha"],
                   "thermal": ["smoky", "clean", "depth", "smoke_alpha"]}
    sensor = {"bits": 14, "gain": 0.01, "offset": 20.0, "netd_k": 0.04}
    for modality, n, (w, h), fps in (("rgb", n_rgb, rgb_size, n_rgb), ("thermal", n_thermal, thermal_size, n_thermal)):
        f = 0.9 * w
        k = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
        frames = []
        for i in range(n):
            ts = i / fps + (0.02 if modality == "thermal" else 0.0)
            t = ts / duration
            ang = -0.9 + 1.8 * i / max(n - 1, 1)
            eye = np.array([3.2 * math.cos(ang), 3.2 * math.sin(ang), 1.8])
            c2w = _look_at_c2w_gl(eye, np.array([0.0, 0.0, 0.3]))
            vm = c2w_gl_to_viewmat(c2w)
            stem = f"{i:04d}"
            split = "test" if modality == "rgb" and i % 4 == 2 else "train"
            frames.append({"index": i, "file_stem": stem, "timestamp_s": ts, "time": min(t, 1.0),
                           "sim_frame": i, "split": split, "transform_matrix": c2w.tolist()})
            sm = _smoke(np.random.default_rng(seed + 100), t, 150, max(opacity, 1e-3))
            key = "thermal" if modality == "thermal" else "rgb"
            bg = sky if modality == "rgb" else None
            clean, depth, _ = _render([surf], key, [1.0], vm, k, w, h, False, bg)
            th_scale = 0.05 if modality == "thermal" else 1.0
            smoky, _, alpha = _render([surf, sm], key, [1.0, th_scale if opacity > 0 else 0.0], vm, k, w, h, True, bg)
            root = path / modality
            if modality == "rgb":
                _png(root / "smoky" / f"{stem}.png", np.round(np.clip(smoky, 0, 1) * 255).astype(np.uint8))
                _png(root / "clean" / f"{stem}.png", np.round(np.clip(clean, 0, 1) * 255).astype(np.uint8))
                if shadowed and split == "test":  # a test-view pass (contracts.dataset_format)
                    dark = clean * (1.0 - 0.5 * alpha[..., None])
                    _png(root / "shadowed" / f"{stem}.png", np.round(np.clip(dark, 0, 1) * 255).astype(np.uint8))
            else:
                rad_s = 40.0 + 30.0 * smoky[..., 0]
                rad_c = 40.0 + 30.0 * clean[..., 0]
                _write_exr(root / "smoky_radiance" / f"{stem}.exr", "L", rad_s)
                _write_exr(root / "clean_radiance" / f"{stem}.exr", "L", rad_c)
                for sub, rad in (("smoky", rad_s), ("clean", rad_c)):
                    counts = np.clip(np.round((rad - sensor["offset"]) / sensor["gain"]), 0, 2 ** 14 - 1)
                    _png(root / sub / f"{stem}.png", counts.astype(np.uint16))
            _write_exr(root / "depth" / f"{stem}.exr", "Z", depth)
            _write_exr(root / "smoke_alpha" / f"{stem}.exr", "A", alpha)
            _png(root / "smoke_mask" / f"{stem}.png", np.where(alpha > 0.02, 255, 0).astype(np.uint8))
        tf = {"modality": modality, "camera_model": "PINHOLE", "w": w, "h": h, "fl_x": f, "fl_y": f,
              "cx": w / 2, "cy": h / 2, "camera_angle_x": 2 * math.atan(w / (2 * f)), "fps": fps,
              "time_offset_s": 0.02 if modality == "thermal" else 0.0, "frames": frames}
        (path / f"transforms_{modality}.json").write_text(json.dumps(tf))
    meta = {"format": "smokeseer-synth-dataset", "format_version": 1, "scene": f"splat-{smoke}", "seed": seed,
            "duration_s": duration, "sim_fps": n_rgb, "passes": meta_passes,
            "smoke": {"present": smoke != "none", "fire": False, "static": static_flag, "mask_threshold": 0.02,
                      "density_scale": opacity},
            "thermal_sensor": sensor, "versions": {"writer": "tests.test_smokeseer_data"}}
    (path / "dataset.json").write_text(json.dumps(meta))
    return path


@pytest.fixture(scope="module")
def splat_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_splat_dataset(tmp_path_factory.mktemp("splat") / "ds", n_rgb=8, n_thermal=6)


def test_loader_reads_every_pass(splat_dataset: Path) -> None:
    scene = load_scene(splat_dataset)
    assert scene.rgb.images.shape == (8, 36, 48, 3)
    assert scene.thermal is not None and scene.thermal.images.shape == (6, 24, 32, 1)
    assert scene.rgb.clean is not None and scene.rgb.masks is not None and scene.rgb.depth is not None
    assert 0.0 <= scene.rgb.images.min() and scene.rgb.images.max() <= 1.0
    # Thermal is normalised by the dataset's own counts range: it spans exactly [0, 1].
    assert scene.thermal.images.min() == pytest.approx(0.0) and scene.thermal.images.max() == pytest.approx(1.0)
    assert [f.split for f in scene.rgb.frames].count("test") == 2
    # OpenGL c2w → OpenCV w2c: the orbit looks at the origin, so the target is in front (+z).
    for f in scene.rgb.frames:
        target_cam = f.viewmat[:3, :3] @ np.array([0.0, 0.0, 0.3]) + f.viewmat[:3, 3]
        assert target_cam[2] > 0
        u = f.K[0, 0] * target_cam[0] / target_cam[2] + f.K[0, 2]
        v = f.K[1, 1] * target_cam[1] / target_cam[2] + f.K[1, 2]
        assert abs(u - f.width / 2) < 1e-6 and abs(v - f.height / 2) < 1e-6


def test_downscale_keeps_intrinsics_consistent(splat_dataset: Path) -> None:
    full = load_scene(splat_dataset)
    half = load_scene(splat_dataset, max_width=24)
    assert half.rgb.images.shape[1:3] == (18, 24)
    np.testing.assert_allclose(half.rgb.frames[0].K[:2], full.rgb.frames[0].K[:2] / 2)
    np.testing.assert_allclose(half.rgb.images[0], full.rgb.images[0].reshape(18, 2, 24, 2, 3).mean((1, 3)), atol=1e-6)


def test_malformed_inputs_name_the_file(splat_dataset: Path, tmp_path: Path) -> None:
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(splat_dataset, bad)
    tf = json.loads((bad / "transforms_rgb.json").read_text())
    tf["frames"][1]["transform_matrix"] = [[1, 0], [0, 1]]
    (bad / "transforms_rgb.json").write_text(json.dumps(tf))
    with pytest.raises(DatasetError, match=r"transforms_rgb\.json.*frames\[1\]\.transform_matrix"):
        load_scene(bad)
    shutil.copy(splat_dataset / "transforms_rgb.json", bad / "transforms_rgb.json")
    (bad / "rgb" / "smoky" / "0003.png").unlink()
    with pytest.raises(DatasetError, match=r"0003\.png: missing file"):
        load_scene(bad)
    (bad / "dataset.json").write_text("{not json")
    with pytest.raises(DatasetError, match="dataset.json"):
        load_scene(bad)


def test_every_image_is_decoded_once_and_checked(splat_dataset: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Loading a generated dataset validates it as ``generate-scene --validate`` does without
    decoding any image twice: the ones training uses are checked as they are read, the other
    inputs (radiance) are read for their check alone, and ground truth (clean, shadowed, depth,
    smoke alpha) is read for the RGB evaluation frames' scores only; with ``all_ground_truth``, as
    conversion tools ask, every file is."""
    import contracts.dataset_format as fmt

    reads: dict[Path, int] = {}

    def counting(real):
        def read(path, *args):
            reads[Path(path)] = reads.get(Path(path), 0) + 1
            return real(path, *args)
        return read

    monkeypatch.setattr(fmt, "read_png", counting(fmt.read_png))
    monkeypatch.setattr(fmt, "read_exr_channel", counting(fmt.read_exr_channel))
    scene = load_scene(splat_dataset, max_width=24)
    files = fmt.dataset_files(splat_dataset, json.loads((splat_dataset / "dataset.json").read_text()))
    scored = {f.file_stem for f in scene.rgb.frames if f.split != "train"}
    assert scored and len(scored) < len(scene.rgb.frames)
    assert set(reads) == {p for p, pf, _ in files if pf.folder not in fmt.GROUND_TRUTH_FOLDERS
                          or (pf.folder in ("rgb/clean", "rgb/shadowed", "rgb/depth") and p.stem in scored)}
    assert set(reads.values()) == {1}
    for truth in (scene.rgb.clean, scene.rgb.shadowed):
        assert np.isnan(truth[scene.rgb.indices("train")]).all()
        assert np.isfinite(truth[scene.rgb.indices("test")]).all()
    reads.clear()
    load_scene(splat_dataset, max_width=24, all_ground_truth=True)
    assert set(reads) == {p for p, _, _ in files} and len(files) == 8 * 5 + 2 + 6 * 7  # shadowed: the 2 test views
    assert set(reads.values()) == {1}


def test_real_capture_with_colmap_text(tmp_path: Path, splat_dataset: Path) -> None:
    """A real-capture layout (COLMAP text poses, timestamps.csv, masks) loads with the same
    cameras as the transforms it was written from."""
    from scipy.spatial.transform import Rotation

    ref = load_scene(splat_dataset)
    cap = tmp_path / "cap"
    for modality, mod in (("rgb", ref.rgb), ("thermal", ref.thermal)):
        assert mod is not None
        sparse = cap / modality / "sparse"
        sparse.mkdir(parents=True)
        f0 = mod.frames[0]
        (sparse / "cameras.txt").write_text(
            f"# comment\n1 PINHOLE {f0.width} {f0.height} {f0.K[0, 0]} {f0.K[1, 1]} {f0.K[0, 2]} {f0.K[1, 2]}\n")
        lines, stamps = [], ["name,timestamp_s"]
        for i, f in enumerate(mod.frames):
            q = Rotation.from_matrix(f.viewmat[:3, :3]).as_quat()  # x y z w
            t = f.viewmat[:3, 3]
            name = f"{f.file_stem}.png"
            lines.append(f"{i + 1} {q[3]} {q[0]} {q[1]} {q[2]} {t[0]} {t[1]} {t[2]} 1 {name}")
            lines.append("")
            stamps.append(f"{name},{f.timestamp_s}")
            src = splat_dataset / modality / "smoky" / name
            (cap / modality / "images").mkdir(parents=True, exist_ok=True)
            (cap / modality / "images" / name).write_bytes(src.read_bytes())
            if modality == "rgb":
                (cap / "rgb" / "masks").mkdir(exist_ok=True)
                (cap / "rgb" / "masks" / name).write_bytes((splat_dataset / "rgb" / "smoke_mask" / name).read_bytes())
        (sparse / "images.txt").write_text("\n".join(lines) + "\n")
        (cap / modality / "timestamps.csv").write_text("\n".join(stamps) + "\n")
    (cap / "capture.json").write_text(json.dumps({"duration_s": 1.0}))
    scene = load_scene(cap)
    assert not scene.synthetic and scene.thermal is not None and scene.rgb.masks is not None
    for a, b in zip(scene.rgb.frames, ref.rgb.frames):
        np.testing.assert_allclose(a.viewmat, b.viewmat, atol=1e-6)
        assert a.time == pytest.approx(b.time, abs=1e-9)
    np.testing.assert_allclose(scene.rgb.images, ref.rgb.images, atol=1e-6)
    np.testing.assert_allclose(scene.thermal.images, ref.thermal.images, atol=1e-6)
    (cap / "rgb" / "sparse" / "cameras.txt").write_text("1 OPENCV 48 36 40 40 24 18 0.1 0 0 0\n")
    with pytest.raises(DatasetError, match="cameras.txt.*OPENCV"):
        load_scene(cap)


def _transforms_capture(src: Path, cap: Path, with_stamps_in_json: bool) -> None:
    """A capture posed by transforms_{rgb,thermal}.json, images copied from a splat dataset."""
    for modality in ("rgb", "thermal"):
        doc = json.loads((src / f"transforms_{modality}.json").read_text())
        (cap / modality / "images").mkdir(parents=True)
        for fr in doc["frames"]:
            name = f"{fr['file_stem']}.png"
            (cap / modality / "images" / name).write_bytes((src / modality / "smoky" / name).read_bytes())
            fr["file_path"] = f"{modality}/images/{name}"
            for key in ("split", "time", "file_stem") + (() if with_stamps_in_json else ("timestamp_s",)):
                fr.pop(key, None)
        (cap / f"transforms_{modality}.json").write_text(json.dumps(doc))


def test_timestamps_csv_is_honoured_with_transforms_poses(splat_dataset: Path, tmp_path: Path) -> None:
    cap = tmp_path / "cap"
    _transforms_capture(splat_dataset, cap, with_stamps_in_json=False)
    ref = load_scene(splat_dataset)
    for modality, mod in (("rgb", ref.rgb), ("thermal", ref.thermal)):
        rows = ["name,timestamp_s"] + [f"{f.file_stem}.png,{f.timestamp_s}" for f in mod.frames]
        (cap / modality / "timestamps.csv").write_text("\n".join(rows) + "\n")
    (cap / "capture.json").write_text(json.dumps({"duration_s": 1.0, "pose_frames": "shared"}))
    scene = load_scene(cap)
    for a, b in zip(scene.thermal.frames, ref.thermal.frames):
        assert a.timestamp_s == pytest.approx(b.timestamp_s) and a.time == pytest.approx(b.time)
    assert max(f.time for f in scene.rgb.frames) == pytest.approx(max(f.time for f in ref.rgb.frames))
    assert any("no smoke masks" in n for n in scene.notes)
    lines = (cap / "thermal" / "timestamps.csv").read_text().splitlines()
    lines[3] = "0002.png,soon"
    (cap / "thermal" / "timestamps.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"thermal/timestamps\.csv: line 4: timestamp 'soon' is not a number"):
        load_scene(cap)
    (cap / "thermal" / "timestamps.csv").write_text("name,timestamp_s\n0000.png,0.1\n")
    with pytest.raises(DatasetError, match=r"timestamps\.csv: no row for frame '0001'"):
        load_scene(cap)


def test_capture_without_timestamps_says_so(splat_dataset: Path, tmp_path: Path) -> None:
    cap = tmp_path / "cap"
    _transforms_capture(splat_dataset, cap, with_stamps_in_json=False)
    scene = load_scene(cap)
    assert sum("frame index used as timestamp" in n for n in scene.notes) == 2


def test_dark_16bit_frames_scale_by_bit_depth(splat_dataset: Path, tmp_path: Path) -> None:
    """A dark 16-bit capture (max 200 counts of 65535) must not be read as 8-bit (257x too bright)."""
    cap = tmp_path / "cap"
    _transforms_capture(splat_dataset, cap, with_stamps_in_json=True)
    brightest = 0
    for p in (cap / "rgb" / "images").glob("*.png"):
        grey = np.asarray(Image.open(p).convert("L"), dtype=np.float64)
        counts = np.round(grey / grey.max() * 200.0).astype(np.uint16)
        brightest = max(brightest, int(counts.max()))
        Image.fromarray(counts).save(p)
    scene = load_scene(cap)
    assert brightest == 200
    assert scene.rgb.images.max() == pytest.approx(200.0 / 65535.0, rel=1e-6)
    assert (cap / "rgb" / "images" / "0000.png").read_bytes()[24] == 16
