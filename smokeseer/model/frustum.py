"""Which points lie near what a camera sees: the view cut of Stage 3's smoke motion
(``deform.view_cull``) deforms only the smoke Gaussians this test keeps."""
from __future__ import annotations

import torch
from torch import Tensor

PAD_PX = 3.0
"""Pixels added to every image edge: the rasterizer's 0.3 px² dilation widens a footprint by
3·√0.3 ≈ 1.6 px and its radius is rounded up to whole pixels (1 px more)."""


def near_frustum(points: Tensor, radius: Tensor, viewmat: Tensor, K: Tensor, width: int, height: int,
                 near_plane: float) -> Tensor:
    """True for each point whose ball of ``radius`` may reach the pyramid the camera sees (the
    image widened by ``PAD_PX`` on every side, beyond ``near_plane``): every bounding plane of the
    pyramid is moved out by the radius. Conservative: a ball that meets the pyramid always passes;
    some that pass (near its edges) do not meet it. ``viewmat`` is world-to-camera (OpenCV axes),
    [4, 4]; ``K`` [3, 3]."""
    pc = points @ viewmat[:3, :3].T + viewmat[:3, 3]
    x, y, z = pc.unbind(-1)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    keep = z >= near_plane - radius
    # Each side plane passes through the camera centre: x = s·z with s the edge's slope; the
    # signed distance of a point outside it is (x - s·z)/√(1 + s²) on the high side.
    for coord, focal, centre, size in ((x, fx, cx, width), (y, fy, cy, height)):
        low, high = -(centre + PAD_PX) / focal, (size - centre + PAD_PX) / focal
        keep &= (low * z - coord) <= radius * torch.sqrt(1 + low * low)
        keep &= (coord - high * z) <= radius * torch.sqrt(1 + high * high)
    return keep
