"""The mask floor's reach (smokeseer/train/mask_floor.py) on two cameras over a plane, worked by hand,
and the mask term with it."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from scenes.load import load_scene
from smokeseer.config import make_config
from smokeseer.stage1.pipeline import run_stage1
from smokeseer.train.losses import mask_alignment
from smokeseer.train.mask_floor import (cube_reach, estimated_alpha_bound, estimated_dense,
                                        never_seen_clear)
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


def _smoky_frames(alpha: np.ndarray, surface: np.ndarray, smoke: np.ndarray) -> np.ndarray:
    """Frames by the image formation I = A + T (J - A): alpha (frames, N, N), J (N, N, 3) on the
    plane z = 5 (camera 1 sees camera 0's column u at u - 2), A (3,)."""
    frames = np.empty((2, N, N, 3))
    frames[0] = smoke + (1 - alpha[0, ..., None]) * (surface - smoke)
    shifted = np.roll(surface, -2, axis=1)  # camera 1's column u sees the plane at camera 0's u + 2
    frames[1] = smoke + (1 - alpha[1, ..., None]) * (shifted - smoke)
    return frames


def test_cube_reach_is_the_longest_step_inside_the_unit_cube() -> None:
    origin = np.array([[0.5, 0.5, 0.5], [0.2, 0.9, 0.5], [0.3, 0.3, 0.3]])
    direction = np.array([[0.25, 0.0, 0.0], [0.1, 0.05, -0.1], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(cube_reach(origin, direction), [2.0, 2.0, np.inf])


@pytest.mark.parametrize("smoke_known", [True, False])
def test_estimated_floor_reads_the_density_off_a_clear_view(smoke_known: bool) -> None:
    """Camera 0's columns 7-9 see points camera 1 sees clear (its columns 5-7), so their surface
    colour is known. With the smoke colour the pixel's alpha is exact and the floor (0.4) acts
    on alpha 0.5 and 0.9 but not 0.1; without it, the lower bound 1 / reach still finds the
    alpha-0.9 pixel and drops the 0.1 one (the 0.5 one is beyond what a bound can tell)."""
    viewmats, Ks, depths, valid = _two_cameras()
    surface = np.full((N, N, 3), 0.1)
    smoke = np.array([0.8, 0.8, 0.8])
    alpha = np.zeros((2, N, N))
    alpha[0, :, :10] = 0.6
    alpha[0, :, 7], alpha[0, :, 8], alpha[0, :, 9] = 0.1, 0.5, 0.9
    alpha[1, :, :5] = 0.3
    masks = (alpha > 0.02).astype(float)
    frames = _smoky_frames(alpha, surface, smoke)
    got = estimated_dense(masks, frames, depths, valid, viewmats, Ks, smoke if smoke_known else None, 0.4)
    assert not got[0, :, 10:].any() and not got[1, :, 5:].any()  # outside the masks: never
    assert not got[0, :, 7].any() and got[0, :, 9].all()
    assert got[0, :, 8].all() == smoke_known
    assert (got == estimated_dense(masks, frames, depths, valid, viewmats, Ks, smoke if smoke_known else None,
                                   0.4)).all()


def test_estimated_floor_on_unpinned_points_takes_the_middle_of_the_bounds() -> None:
    """Camera 0's columns 2-4 land on camera 1's smoke (alpha 0.3 there), so no view sees them
    clear; grey smoke A = 0.8. Worked by hand (per channel; lower bound 1 - r0 / max(r0, r1)
    with r = |I - A|, upper bound 1 - r0 / 0.8):
    - column 2, dark surface 0.1 under alpha 0.9: I0 = 0.73, I1 = 0.31; bounds 0.857 and 0.913,
      floor kept;
    - column 3, dark surface under alpha 0.05: I0 = 0.135, I1 = 0.31; bounds 0 and 0.169,
      provably thin, dropped;
    - column 4, surface 0.6 under alpha 0.05: I0 = 0.61, I1 = 0.66; bounds 0 and 0.763, the
      middle 0.381 is under the floor, dropped (the upper bound alone could not rule it out).
    Without a smoke colour (the lines do not meet) no unpinned pixel keeps the floor."""
    viewmats, Ks, depths, valid = _two_cameras()
    smoke = np.array([0.8, 0.8, 0.8])
    surface = np.full((N, N, 3), 0.1)
    surface[:, 4] = 0.6
    alpha = np.zeros((2, N, N))
    alpha[0, :, 2], alpha[0, :, 3], alpha[0, :, 4] = 0.9, 0.05, 0.05
    alpha[1, :, :5] = 0.3
    masks = (alpha > 0.02).astype(float)
    frames = _smoky_frames(alpha, surface, smoke)
    np.testing.assert_allclose(frames[0, 0, 2:5, 0], [0.73, 0.135, 0.61])
    np.testing.assert_allclose(frames[1, 0, 0:3, 0], [0.31, 0.31, 0.66])
    got = estimated_dense(masks, frames, depths, valid, viewmats, Ks, smoke, 0.4)
    assert got[0, :, 2].all() and not got[0, :, 3].any() and not got[0, :, 4].any()
    thin = estimated_dense(masks, frames, depths, valid, viewmats, Ks, None, 0.4)
    assert not thin[0, :, 2:5].any() and not (thin & ~got).any()


def _pinned_and_unpinned() -> tuple[np.ndarray, ...]:
    """The two hand-worked cases together: camera 0's columns 7-9 seen clear by camera 1 (alpha 0.1,
    0.5, 0.9), its columns 2-4 seen by no view clear (as above), grey smoke 0.8, and camera 0's top
    row not covered by the geometry. (viewmats, Ks, depths, valid, smoke, alpha, masks, frames)."""
    viewmats, Ks, depths, valid = _two_cameras()
    smoke = np.array([0.8, 0.8, 0.8])
    surface = np.full((N, N, 3), 0.1)
    surface[:, 4] = 0.6
    alpha = np.zeros((2, N, N))
    alpha[0, :, :10] = 0.6
    alpha[0, :, 2], alpha[0, :, 3], alpha[0, :, 4] = 0.9, 0.05, 0.05
    alpha[0, :, 7], alpha[0, :, 8], alpha[0, :, 9] = 0.1, 0.5, 0.9
    alpha[1, :, :5] = 0.3
    masks = (alpha > 0.02).astype(float)
    frames = _smoky_frames(alpha, surface, smoke)
    valid[0, 0] = False  # camera 0's top row: the geometry does not cover it
    return viewmats, Ks, depths, valid, smoke, alpha, masks, frames


def test_the_bound_target_is_what_the_images_prove_and_never_more() -> None:
    """estimated-bound on the two hand-worked cases above. Pinned (camera 0's columns 7-9, seen clear
    by camera 1): with the smoke colour the exact alpha 0.1, 0.5, 0.9; without it the lower bound
    1 / reach, never above the truth. Unpinned (columns 2-4 with the colour): the lower bounds 0.857,
    0 and 0, each at most the truth (0.9, 0.05, 0.05); without the colour, 0. Uncovered masked pixels
    take the floor given; unmasked pixels 0."""
    viewmats, Ks, depths, valid, smoke, alpha, masks, frames = _pinned_and_unpinned()
    known = estimated_alpha_bound(masks, frames, depths, valid, viewmats, Ks, smoke, 0.4)
    np.testing.assert_allclose(known[0, 1:, 7:10], np.broadcast_to([0.1, 0.5, 0.9], (N - 1, 3)), atol=1e-9)
    np.testing.assert_allclose(known[0, 1:, 2:5], np.broadcast_to([0.857143, 0.0, 0.0], (N - 1, 3)), atol=1e-6)
    assert (known[0, 0, :10] == 0.4).all() and (known[0, :, 10:] == 0).all() and (known[1, :, 5:] == 0).all()
    unknown = estimated_alpha_bound(masks, frames, depths, valid, viewmats, Ks, None, 0.4)
    assert (unknown[0, 1:, 2:5] == 0).all()
    assert (unknown[0, 1:, 7:10] <= alpha[0, 1:, 7:10] + 1e-9).all() and (unknown[0, 1:, 9] > 0.5).all()
    # the step's reading of the same estimate: the floor acts exactly where the bound's pinned alpha reaches it
    step = estimated_dense(masks, frames, depths, valid, viewmats, Ks, smoke, 0.4)
    assert (step[0, 1:, 7:10] == (known[0, 1:, 7:10] >= 0.4)).all()


def test_mask_term_with_targets_pushes_up_to_each_pixels_target_and_never_down() -> None:
    alpha = torch.tensor([[0.1, 0.6, 0.2, 0.3, 0.0]], requires_grad=True)
    mask = torch.tensor([[1.0, 1.0, 1.0, 0.0, 0.0]])
    targets = torch.tensor([[0.5, 0.4, 0.0, 0.0, 0.0]])
    loss = mask_alignment(alpha, mask, 0.4, targets=targets)
    assert loss.item() == pytest.approx((0.4 + 0.0 + 0.0 + 0.3 + 0.0) / 5)
    loss.backward()
    assert alpha.grad[0, 0] < 0 and alpha.grad[0, 1] == 0 and alpha.grad[0, 2] == 0 and alpha.grad[0, 3] > 0


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


def _old_mask_term(alpha: torch.Tensor, mask: torch.Tensor, floor: float, where: torch.Tensor) -> torch.Tensor:
    """The term as written before it took weights: alpha counted as full smoke inside the mask
    where it reaches the floor or the floor does not act."""
    full = (alpha >= floor) | ~where
    return (torch.where((mask > 0.5) & full, torch.ones_like(alpha), alpha) - mask).abs().mean()


def test_a_weighted_floor_blends_the_term_with_and_without_it() -> None:
    """A floor weight of 0 or 1 gives the bool rule's value and gradient to the last bit (so
    ``present`` trains as before); a weight between is the same blend of the two terms, value
    and gradient, so a floor that moves a little moves the loss a little."""
    gen = torch.Generator().manual_seed(0)
    alpha0 = torch.rand(4, 9, 11, generator=gen)
    mask = (torch.rand(4, 9, 11, generator=gen) > 0.4).float() * torch.rand(4, 9, 11, generator=gen).clamp(min=0.6)
    where = torch.rand(4, 9, 11, generator=gen) > 0.5

    def value_and_grad(fn):
        a = alpha0.clone().requires_grad_(True)
        loss = fn(a)
        loss.backward()
        return loss.detach(), a.grad

    old, old_grad = value_and_grad(lambda a: _old_mask_term(a, mask, 0.4, where))
    for given in (where, where.float()):
        new, new_grad = value_and_grad(lambda a: mask_alignment(a, mask, 0.4, given))
        assert new.item() == old.item() and torch.equal(new_grad, old_grad)
    on, on_grad = value_and_grad(lambda a: mask_alignment(a, mask, 0.4, torch.ones_like(mask)))
    off, off_grad = value_and_grad(lambda a: mask_alignment(a, mask, 0.4, torch.zeros_like(mask)))
    half, half_grad = value_and_grad(lambda a: mask_alignment(a, mask, 0.4, torch.full_like(mask, 0.3)))
    assert half.item() == pytest.approx(0.3 * on.item() + 0.7 * off.item(), rel=1e-6)
    torch.testing.assert_close(half_grad, 0.3 * on_grad + 0.7 * off_grad)
    assert off.item() < half.item() < on.item()


def test_the_floor_reads_the_meeting_as_the_setting_says() -> None:
    """``present`` takes the rule with the point wherever enough lines meet, whatever its weight;
    ``trusted`` blends the rule with the point and without it by the point's weight, so two runs
    whose line counts straddle the estimate's start (food_plate's 106 and 98) get nearly one floor."""
    from smokeseer.api import by_meeting
    from smokeseer.stage1.haze_lines import SmokeColourEstimate

    calls: list[object] = []

    def rule(colour: np.ndarray | None) -> np.ndarray:
        calls.append(None if colour is None else tuple(colour))
        return np.array([True, colour is not None, False])

    point = np.array([0.3, 0.3, 0.3])
    for weight, expected in ((0.0, [1, 0, 0]), (0.02, [1, 0.02, 0]), (0.5, [1, 0.5, 0]), (1.0, [1, 1, 0])):
        est = SmokeColourEstimate(point, 106, 300, 0.5, meeting=point, meeting_weight=weight)
        calls.clear()
        np.testing.assert_allclose(by_meeting(rule, est, "trusted"), expected, atol=1e-7)
        assert len(calls) == 1 + (0.0 < weight < 1.0)
        np.testing.assert_array_equal(by_meeting(rule, est, "present"), [True, True, False])
    nothing = by_meeting(rule, None, "trusted")
    assert nothing.dtype == np.float32 and nothing.tolist() == [1, 0, 0]
    unmet = SmokeColourEstimate(point, 500, 900, 0.1, meeting=None, meeting_weight=0.0)
    assert by_meeting(rule, unmet, "present").tolist() == by_meeting(rule, unmet, "trusted").tolist() == [1, 0, 0]


def test_bad_setting_names_the_field() -> None:
    with pytest.raises(ValueError, match="loss.mask_floor_where: 'sometimes' is not one of all, never-clear, estimated-meeting, estimated-bound"):
        make_config("full", "quick", overrides={"loss.mask_floor_where": "sometimes"})
    with pytest.raises(ValueError, match="loss.mask_floor_where: estimated-meeting .* stage3.smoke_color=haze-lines"):
        make_config("full", "quick", overrides={"loss.mask_floor_where": "estimated-meeting",
                                                "stage3.smoke_color": "learned"})
    with pytest.raises(ValueError, match="loss.mask_floor_meeting: 'always' is not one of present, trusted"):
        make_config("full", "quick", overrides={"loss.mask_floor_meeting": "always"})


def test_floor_rule_follows_the_setting_and_needs_masks_and_smoke(tmp_path) -> None:
    """The plan takes the configured rule, with Stage 1's masks from the dataset or estimated,
    and "all" (nothing to gate) by default."""
    ds = write_splat_dataset(tmp_path / "ds", n_rgb=4, n_thermal=3)
    for stage1 in ("ground-truth", "estimate"):
        for where in ("never-clear", "estimated-meeting", "estimated-bound"):
            cfg = make_config("full", "quick", overrides={"loss.mask_floor_where": where, "stage1": stage1,
                                                          "stage3.smoke_color": "haze-lines"})
            scene = load_scene(ds, cfg.max_width)
            run_stage1(cfg, scene)
            plan = plan_stage3(cfg, scene)
            assert plan.mask_floor == where and plan.record()["mask_floor"] == where
    assert plan_stage3(make_config("full", "quick"), scene).mask_floor == "all"
