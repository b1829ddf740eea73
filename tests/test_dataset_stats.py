"""The statistics of dataset.json (generator/dataset_stats.py, contracts/unrecoverable.py) against
cases whose answer is known by hand: smoke of known optical depth, cameras over a plane with
occluders, thick smoke and sky, and warm objects of known temperature."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from contracts.imageio import write_exr, write_png
from contracts.unrecoverable import DepthView, unrecoverable_mask
from generator.dataset_stats import MAX_OPTICAL_DEPTH, scene_stats, thermal_contrast
from generator.optics.planck import band_radiance
from generator.spec import parse_spec

H, W, F = 30, 40, 30.0


def _transforms(root: Path, modality: str, splits: list[str], times: list[float]) -> None:
    frames = [{"index": i, "file_stem": f"{i:04d}", "timestamp_s": t, "time": t, "sim_frame": 1, "split": s,
               "transform_matrix": np.eye(4).tolist()} for i, (s, t) in enumerate(zip(splits, times))]
    (root / f"transforms_{modality}.json").write_text(json.dumps(
        {"modality": modality, "w": W, "h": H, "fl_x": F, "fl_y": F, "cx": W / 2, "cy": H / 2, "frames": frames}))


def _alpha_pass(root: Path, modality: str, stem: str, alpha: np.ndarray) -> None:
    write_exr(root / modality / "smoke_alpha" / f"{stem}.exr", {"A": alpha.astype(np.float32)})
    write_png(root / modality / "smoke_mask" / f"{stem}.png", np.where(alpha > 0.02, 255, 0).astype(np.uint8))


def test_optical_depth_of_known_smoke_over_the_test_views(tmp_path: Path) -> None:
    """alpha = 1 - exp(-tau) gives back tau; opaque pixels count at ln 255; only test views count,
    and LWIR takes the thermal frame nearest in time to each RGB test view."""
    tau = np.zeros((H, W))
    tau[:, :10], tau[:, 10:20] = 0.3, 2.0  # a quarter at 0.3, a quarter at 2.0, half clear
    test_alpha = 1.0 - np.exp(-tau)
    test_alpha[0, :] = 1.0  # one opaque row: clipped at 1 - 1/255
    _transforms(tmp_path, "rgb", ["train", "test"], [0.0, 1.0])
    _alpha_pass(tmp_path, "rgb", "0000", np.full((H, W), 0.9))  # a training view: not counted
    _alpha_pass(tmp_path, "rgb", "0001", test_alpha)
    _transforms(tmp_path, "thermal", ["train", "train"], [0.1, 0.8])
    _alpha_pass(tmp_path, "thermal", "0000", np.full((H, W), 0.5))
    _alpha_pass(tmp_path, "thermal", "0001", np.full((H, W), 1.0 - math.exp(-0.05)))
    meta = {"passes": {"rgb": ["smoke_alpha"], "thermal": ["smoke_alpha"]}, "smoke": {"mask_threshold": 0.02}}
    views = scene_stats(tmp_path, meta)["test_views"]
    expected = tau.copy()
    expected[0, :] = math.log(255.0)
    assert MAX_OPTICAL_DEPTH == pytest.approx(math.log(255.0))
    assert views["views"] == 1
    assert views["rgb_optical_depth"] == pytest.approx(expected.mean(), rel=1e-5)
    smoke = test_alpha > 0.02
    assert views["smoke_fraction"] == pytest.approx(smoke.mean())
    assert views["rgb_optical_depth_in_smoke"] == pytest.approx(expected[smoke].mean(), rel=1e-5)
    assert views["lwir_optical_depth"] == pytest.approx(0.05, rel=1e-5)  # frame 0001 (t 0.8) is nearest to t 1.0
    assert "unrecoverable_share" not in views  # no depth pass: not computed


def _view(x_px: float, y_px: float, depth: np.ndarray, alpha: np.ndarray) -> DepthView:
    """A camera 5 m over the ground plane z = 0, looking straight down (identity rotation: it looks
    along -Z), moved from the test camera by (x_px, y_px) pixels' worth of ground (1/6 m each)."""
    c2w = np.eye(4)
    c2w[:3, 3] = (x_px * 5 / F, y_px * 5 / F, 5.0)
    return DepthView(c2w, F, F, W / 2, H / 2, depth, alpha)


def test_unrecoverable_share_of_a_hand_built_scene() -> None:
    """Cameras over a plane, 40x30 pixels. The training views sit half a pixel off the test view's
    grid, so a test pixel's point lands between four of their pixel centres, never on one: in
    training view B (8.5 pixels right, half a pixel up) at columns u - 9, u - 8 and rows v, v + 1.
    B has sky in rows 0-4, a pole 3 m tall over rows 10-19, columns 10-19, thick smoke (alpha
    0.11) over rows 20-29, columns 20-29 and thin smoke (0.09) beside it. Training view A (half a
    pixel left and up: columns u, u + 1) is behind opaque smoke but for rows 0-9, columns 0-9.

    Ground test view, pixels B cannot see: columns 0-7 (out of B's frame), 8 x 30 = 240; rows 0-3
    (B's four pixels show sky, not the ground) in columns 8-39, 4 x 32 = 128; behind the pole, rows
    10-18 x columns 19-27 = 81; under the thick smoke, rows 20-29 x columns 29-37 = 90. A sees rows
    0-9 x columns 0-9: 80 + 8 of them in the first two sets. Unrecoverable: 539 - 88 = 451.
    A sky test view: its pixels are directions, which B's translation does not move, so they land
    on B's pixel centres (a tie between rows; row 5 is left out): rows 0-4 are seen through B's
    sky, rows 6-29 are not. A sees no sky at all."""
    ground = np.full((H, W), 5.0)
    alpha_b = np.zeros((H, W))
    alpha_b[20:, 20:30], alpha_b[20:, 30:] = 0.11, 0.09
    depth_b = ground.copy()
    depth_b[:5] = 0.0
    depth_b[10:20, 10:20] = 2.0
    alpha_a = np.ones((H, W))
    alpha_a[:10, :10] = 0.0
    training = [_view(-0.5, 0.5, ground, alpha_a), _view(8.5, 0.5, depth_b, alpha_b)]

    mask = unrecoverable_mask(_view(0.0, 0.0, ground, np.zeros((H, W))), training)
    assert mask.sum() == 451
    assert mask[10:, :8].all() and not mask[:10, :10].any()
    assert mask[:4, 10:].all() and not mask[4:10, 10:].any()
    assert mask[10:19, 19:28].all() and not mask[19, 19:28].any() and not mask[10:19, 28].any()
    assert mask[20:, 29:38].all() and not mask[20:, 38:].any() and not mask[20:, 28].any()

    sky = unrecoverable_mask(_view(0.0, 0.0, np.zeros((H, W)), np.zeros((H, W))), training)
    assert not sky[:5].any() and sky[6:].all()


def test_thermal_contrast_of_warm_objects_of_known_temperature(tmp_path: Path) -> None:
    """Blackbody surfaces at 293 K (ambient) and 296 K, a person at 308 K and sky: warm materials
    are those 10 K above ambient, the split lies halfway to the coolest (300.5 K), and the contrast
    is the median warm temperature less the median of the other surface pixels; the sky is neither."""
    spec = parse_spec({
        "name": "warm", "lights": {"ambient_temperature_k": 293.0},
        "materials": {m: {"temperature_k": t, "emissivity": 1.0} for m, t in
                      (("ground", 293.0), ("wall", 296.0), ("skin", 308.0), ("unused", 400.0))},
        "objects": [{"name": n, "asset": "box", "material": n} for n in ("ground", "wall", "skin")]}, "warm.yaml")
    band = (8e-6, 14e-6)
    temperature = np.full((H, W), 293.0)
    temperature[:, 25:30], temperature[:, 30:] = 296.0, 308.0
    depth = np.full((H, W), 4.0)
    depth[:5] = 0.0  # sky rows, warm-looking or not, are not surface
    temperature[:5] = 350.0
    _transforms(tmp_path, "thermal", ["train"], [0.0])
    write_exr(tmp_path / "thermal" / "clean_radiance" / "0000.exr", {"L": band_radiance(temperature, band)})
    write_exr(tmp_path / "thermal" / "depth" / "0000.exr", {"Z": depth})
    out = thermal_contrast(tmp_path, spec, (8.0, 14.0))
    assert out["warm_materials"] == ["skin"] and out["split_k"] == pytest.approx(300.5)
    assert out["warm_fraction"] == pytest.approx(10 / 40)
    assert out["warm_k"] == pytest.approx(308.0, abs=1e-3) and out["surroundings_k"] == pytest.approx(293.0, abs=1e-3)
    assert out["contrast_k"] == pytest.approx(15.0, abs=2e-3)
    cold = parse_spec({"name": "cold", "materials": {"ground": {"temperature_k": 293.15}},
                       "objects": [{"name": "g", "asset": "box", "material": "ground"}]}, "cold.yaml")
    assert thermal_contrast(tmp_path, cold, (8.0, 14.0))["contrast_k"] is None
