"""The mask floor's reach (smokeseer/train/mask_floor.py) on two cameras over a plane, worked by hand,
and the mask term with it."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from contracts.imageio import read_exr_channel
from scenes.generated import load_smoke_alpha
from scenes.load import load_scene
from smokeseer.config import make_config
from smokeseer.stage1.pipeline import run_stage1
from smokeseer.train.losses import mask_alignment
from smokeseer.train.mask_floor import never_seen_clear
from smokeseer.train.plan import plan_stage3
from tests.test_smokeseer_data import write_splat_dataset

N = 20


def _two_cameras() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Camera 0 at the origin, camera 1 moved +0.5 along x, both looking along +z at the plane
    z = 5. A pixel column u of camera 0 lands on column u - 2 of camera 1 (20 px focal length)."""
    K = np.array([[20.0, 0, 10], [0, 20.0, 10], [0, 0, 1]])
    v0, v1 = np.eye(4), np.eye(4)
    v1[0, 3] = -0.5
    depths = np.full((2, N, N), 5.0)
    return np.stack([v0, v1]), np.stack([K, K]), depths, np.ones((2, N, N), bool)


def test_floor_only_where_no_other_frame_sees_the_point_clear() -> None:
    viewmats, Ks, depths, valid = _two_cameras()
    masks = np.zeros((2, N, N))
    masks[0, :, :10] = 1.0  # camera 0: columns 0-9 smoky
    masks[1, :, :5] = 1.0  # camera 1: columns 0-4 smoky, 5 on clear
    floor = never_seen_clear(masks, depths, valid, viewmats, Ks)
    # Camera 0's columns 0-1 leave camera 1's image, 2-6 land on its smoke, 7-9 on clear pixels.
    assert floor[0, :, :7].all() and not floor[0, :, 7:].any()
    # Camera 1's smoky columns land on camera 0's columns 2-6, all smoky there.
    assert floor[1, :, :5].all() and not floor[1, :, 5:].any()


def test_a_hidden_clear_view_does_not_count_and_uncovered_pixels_keep_the_floor() -> None:
    viewmats, Ks, depths, valid = _two_cameras()
    masks = np.zeros((2, N, N))
    masks[0, :, :10] = 1.0
    masks[1, :, :5] = 1.0
    depths[1, :, 5:8] = 3.0  # something in front of the plane in camera 1's columns 5-7
    valid[0, :3] = False  # camera 0's top rows: the geometry does not cover them
    floor = never_seen_clear(masks, depths, valid, viewmats, Ks)
    assert floor[0, :, :10].all()
    assert not floor[0, :, 10:].any()


def test_mask_term_without_floor_keeps_only_the_push_to_zero() -> None:
    alpha = torch.tensor([[0.1, 0.1, 0.5, 0.3]], requires_grad=True)
    mask = torch.tensor([[1.0, 1.0, 0.0, 0.0]])
    everywhere = mask_alignment(alpha, mask, 0.4)
    assert everywhere.item() == pytest.approx((0.9 + 0.9 + 0.5 + 0.3) / 4)
    assert mask_alignment(alpha, mask, 0.4, torch.ones_like(mask, dtype=torch.bool)).item() == everywhere.item()
    gated = mask_alignment(alpha, mask, 0.4, torch.tensor([[False, True, False, False]]))
    assert gated.item() == pytest.approx((0.0 + 0.9 + 0.5 + 0.3) / 4)
    gated.backward()
    assert alpha.grad[0, 0] == 0 and alpha.grad[0, 1] < 0 and alpha.grad[0, 2] > 0


def test_bad_setting_names_the_field() -> None:
    with pytest.raises(ValueError, match="loss.mask_floor_where: 'sometimes' is not one of all, never-clear, dense"):
        make_config("full", "quick", overrides={"loss.mask_floor_where": "sometimes"})


def test_dense_floor_reads_the_true_alpha_at_the_training_resolution(tmp_path) -> None:
    """load_smoke_alpha is the EXR's alpha averaged over 2x2 blocks when the frames are halved
    (48 -> 24 px wide), computed here with a plain reshape."""
    scene = load_scene(write_splat_dataset(tmp_path / "ds", n_rgb=4, n_thermal=3), max_width=24)
    assert scene.rgb.images.shape[1:3] == (18, 24)
    got = load_smoke_alpha(scene, [1, 3])
    for row, i in zip(got, (1, 3)):
        full = read_exr_channel(tmp_path / "ds" / "rgb" / "smoke_alpha" / f"{i:04d}.exr", "A")
        np.testing.assert_allclose(row, full.reshape(18, 2, 24, 2).mean(axis=(1, 3)), rtol=1e-6)
    assert got.dtype == np.float32 and 0 < got.max() <= 1


def test_dense_floor_needs_the_generators_masks(tmp_path) -> None:
    """With Stage 1's masks from the dataset the rule is "dense"; with estimated masks the true
    alpha would say more than the masks do, so the run keeps "never-clear" and notes it."""
    ds = write_splat_dataset(tmp_path / "ds", n_rgb=4, n_thermal=3)
    for stage1, expected in (("ground-truth", "dense"), ("estimate", "never-clear")):
        cfg = make_config("full", "quick", overrides={"loss.mask_floor_where": "dense", "stage1": stage1})
        scene = load_scene(ds, cfg.max_width)
        report = run_stage1(cfg, scene)
        plan = plan_stage3(cfg, scene, report.masks)
        assert plan.mask_floor == expected and plan.record()["mask_floor"] == expected
        assert any("needs the generator's smoke alpha" in n for n in plan.notes) == (expected == "never-clear")
    assert plan_stage3(make_config("full", "quick"), scene, report.masks).mask_floor == "all"
