"""The mask floor's reach (smokeseer/mask_floor.py) on two cameras over a plane, worked by hand,
and the mask term with it."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from smokeseer.config import make_config
from smokeseer.losses import mask_alignment
from smokeseer.mask_floor import never_seen_clear

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
    with pytest.raises(ValueError, match="loss.mask_floor_where: 'sometimes' is not one of all, never-clear"):
        make_config("full", "quick", overrides={"loss.mask_floor_where": "sometimes"})
