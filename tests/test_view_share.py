"""ViewShare (stage3.thermal_surface_grad=smoky-views): per surface Gaussian, the mean of Stage 1's
smoke masks over the RGB training views its centre lands in, refreshed at each block of
SHARE_REFRESH iterations and when densification changes the count, read once per iteration."""
from __future__ import annotations

import numpy as np
import torch

from smokeseer.model.gaussians import GaussianSet
from smokeseer.train.stage3 import SHARE_REFRESH, ViewShare


def _surface(points: list[list[float]]) -> GaussianSet:
    n = len(points)
    return GaussianSet({"means": torch.tensor(points, dtype=torch.float32), "quats": torch.eye(4)[:1].repeat(n, 1),
                        "log_scales": torch.zeros(n, 3), "opacity": torch.zeros(n, 1)})


def _two_cameras() -> ViewShare:
    """Two cameras looking along +z, 20 px focal length, 20 x 20 px: a point on the axis at depth 5
    lands on column 10 of camera 0 and column 8 of camera 1 (moved +0.5 along x), row 10 in both."""
    K = np.array([[20.0, 0, 10], [0, 20.0, 10], [0, 0, 1]])
    v0, v1 = np.eye(4), np.eye(4)
    v1[0, 3] = -0.5
    masks = np.zeros((2, 20, 20), dtype=np.float32)
    masks[0, 10, 10], masks[1, 10, 8] = 0.8, 0.2
    return ViewShare(masks, np.stack([v0, v1]), np.stack([K, K]))


def test_the_share_is_the_masks_mean_over_the_views_a_centre_lands_in() -> None:
    """A point far to the side lands in neither view and reads 1; after a densification the share is
    recomputed for the new count."""
    share = _two_cameras()
    got = share.at(1, _surface([[0.0, 0.0, 5.0], [50.0, 0.0, 5.0]]))
    torch.testing.assert_close(got, torch.tensor([0.5, 1.0]))
    again = share.at(2, _surface([[0.0, 0.0, 5.0], [50.0, 0.0, 5.0], [0.0, 0.0, 5.0]]))
    torch.testing.assert_close(again, torch.tensor([0.5, 1.0, 0.5]))


def test_the_share_is_read_once_per_block() -> None:
    """The start's read at iteration 1 serves iteration 1; within a block a moved point keeps its
    share; the next block's first iteration reads the new position."""
    share = _two_cameras()
    on_axis, aside = _surface([[0.0, 0.0, 5.0]]), _surface([[50.0, 0.0, 5.0]])
    torch.testing.assert_close(share.at(1, on_axis), torch.tensor([0.5]))
    torch.testing.assert_close(share.at(1, aside), torch.tensor([0.5]))
    torch.testing.assert_close(share.at(SHARE_REFRESH, aside), torch.tensor([0.5]))
    torch.testing.assert_close(share.at(SHARE_REFRESH + 1, aside), torch.tensor([1.0]))
