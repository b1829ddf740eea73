"""Where the mask term's density floor applies (``loss.mask_floor_where``).

Inside the smoke mask the mask term counts smoke alpha at or above ``loss.mask_alpha_floor`` as
full smoke and pushes lower alpha up. That push is what keeps a surface that is always under
dense smoke from absorbing the smoke (room: the surface would take the smoke's colour). Where
the smoke is thin it forces smoke that is not there, and the smoke Gaussians then carry the
scene's own colours over a surface left unconstrained (food_plate's clearing frames, house's
thin plume: validation +2.4 and +1.2 dB with the floor at 0.02, but room and forest lose 1.8-2.3 dB).
The floor is only needed where the images cannot separate surface from smoke: a surface point
that some other training view sees smoke-free has its colour pinned there, and the render loss
can set the smoke over it. So with ``never-clear`` the floor acts only on masked pixels whose
surface point (Stage 2's geometry, rendered as depth at the RGB training cameras) no other
training frame sees outside its mask; pixels the geometry does not cover keep the floor.
"""
from __future__ import annotations

import numpy as np

from scenes.cameras import backproject
from smokeseer.stage1.haze_lines import observations

DEPTH_TOLERANCE = 0.03
"""Another frame sees the point when its rendered depth there is within this fraction of the
point's depth (the haze-line estimate's tolerance, for the same geometry)."""


def never_seen_clear(masks: np.ndarray, depths: np.ndarray, valid: np.ndarray, viewmats: np.ndarray,
                     Ks: np.ndarray, tolerance: float = DEPTH_TOLERANCE) -> np.ndarray:
    """(frames, H, W) bool: masked pixels whose surface point no other frame sees smoke-free.

    ``masks`` (frames, H, W) in [0, 1] (above 0.5 is smoke), ``depths`` planar depth rendered from
    the geometry at the same cameras, ``valid`` where the geometry covers the pixel."""
    n_frames, height, width = masks.shape
    smoky = masks > 0.5
    floor = smoky & ~valid
    for ref in range(n_frames):
        vs, us = np.nonzero(smoky[ref] & valid[ref])
        if len(vs) == 0:
            continue
        points = backproject(depths[ref, vs, us].astype(np.float64), np.stack([us, vs], 1), viewmats[ref], Ks[ref])
        mask_seen, seen = observations(points, masks[..., None], depths, valid, viewmats, Ks, tolerance)
        clear = seen & (mask_seen[..., 0] <= 0.5)
        clear[ref] = False
        floor[ref, vs, us] = ~clear.any(axis=0)
    return floor
