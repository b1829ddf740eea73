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
surface point (the geometry Stage 3 starts from, rendered as depth at the RGB training cameras)
no other training frame sees outside its mask; pixels the geometry does not cover keep the floor.

``estimated-meeting`` goes one step further and reads how dense the smoke is off the images
themselves, with the image formation I = A + T (J - A) (smoke colour A, surface colour J,
transmittance T): the frames that see one surface point give colours on a line through A. A is
the point where the haze lines meet (``smokeseer.stage1.haze_lines``), also when it is too bright
for Stage 3 to hold: a scattering smoke's colour varies with the view, but the meeting point
still places its density.

- A point seen smoke-free elsewhere has its surface colour J there (the mean of those views). With
  A, the pixel's smoke alpha 1 - T is the projection of I - J on A - J; without it,
  |I - J| over the longest step from J towards I inside the colour cube is a lower bound. The
  floor acts where that reaches the floor: such a point's colour is pinned by the clear view, so
  a floor missed costs little, and one forced on thin smoke costs much.
- A point never seen clear has nothing to pin it. With A its alpha lies between two bounds:
  1 - |I - A| / max_i |I_i - A| over the views that see it (as if its clearest view were clear),
  and 1 - |I - A| over the longest step from A towards I inside the cube (as if the surface were
  at the cube's edge). The floor acts where their midpoint reaches it. On the standard datasets
  the upper bound alone kept the floor on 83 % of the excavator's masked pixels (19 % are that
  dense) and the lower bound alone on 54 % of room's (97 %); the midpoint keeps 55 % and 91 %
  (``benchmarks/mask_floor_agreement.py``). Where the lines do not meet there is no A, the smoke
  reads thin, and such a point gets no floor: on house, whose lines do not meet, the truth is
  dense on 7 % of the masked pixels, and keeping the floor on every such point marked 45-59 %.

It needs nothing a real capture lacks: Stage 1's masks, the smoky frames, Stage 2's geometry
and the smoke colour Stage 3 holds.
"""
from __future__ import annotations

import numpy as np

from scenes.cameras import backproject
from smokeseer.stage1.haze_lines import HazeLineSettings, observations

DEPTH_TOLERANCE = HazeLineSettings().depth_tolerance
"""Another frame sees the point when its rendered depth there is within this fraction of the
point's depth: the haze-line estimate's tolerance, for the same geometry."""


def _views_of_masked_points(values: np.ndarray, masks: np.ndarray, depths: np.ndarray, valid: np.ndarray,
                            viewmats: np.ndarray, Ks: np.ndarray, tolerance: float):
    """For each frame: its masked pixels the geometry covers (rows, columns), ``values`` (frames,
    H, W, C, the mask last) as every frame sees their surface points, which frames see them, and
    which other frames see them smoke-free (mask at most 0.5)."""
    smoky = masks > 0.5
    for ref in range(masks.shape[0]):
        vs, us = np.nonzero(smoky[ref] & valid[ref])
        if len(vs) == 0:
            continue
        points = backproject(depths[ref, vs, us].astype(np.float64), np.stack([us, vs], 1), viewmats[ref], Ks[ref])
        seen_values, seen = observations(points, values, depths, valid, viewmats, Ks, tolerance)
        clear = seen & (seen_values[..., -1] <= 0.5)
        clear[ref] = False
        yield ref, vs, us, seen_values, seen, clear


def never_seen_clear(masks: np.ndarray, depths: np.ndarray, valid: np.ndarray, viewmats: np.ndarray,
                     Ks: np.ndarray, tolerance: float = DEPTH_TOLERANCE) -> np.ndarray:
    """(frames, H, W) bool: masked pixels whose surface point no other frame sees smoke-free.

    ``masks`` (frames, H, W) in [0, 1] (above 0.5 is smoke), ``depths`` planar depth rendered from
    the geometry at the same cameras, ``valid`` where the geometry covers the pixel."""
    floor = (masks > 0.5) & ~valid
    for ref, vs, us, _, _, clear in _views_of_masked_points(masks[..., None], masks, depths, valid, viewmats, Ks,
                                                            tolerance):
        floor[ref, vs, us] = ~clear.any(axis=0)
    return floor


def cube_reach(origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(n,) the s ≥ 0 at which ``origin + s * direction`` (both (n, 3)) leaves the colour cube
    [0, 1]^3: the longest step inside the cube in units of ``direction``; inf for a zero direction."""
    with np.errstate(divide="ignore", invalid="ignore"):
        up = np.where(direction > 0, (1.0 - origin) / direction, np.inf)
        down = np.where(direction < 0, -origin / direction, np.inf)
    return np.clip(np.minimum(up, down).min(axis=1), 0.0, None)


def _alpha_estimates(masks: np.ndarray, images: np.ndarray, depths: np.ndarray, valid: np.ndarray,
                     viewmats: np.ndarray, Ks: np.ndarray, smoke_colour: np.ndarray | None, tolerance: float):
    """Per frame, what the images say of the smoke alpha of its masked pixels the geometry covers
    (the module docstring): (frame, rows, columns, whether another view sees the point clear, the
    alpha read off that clear view, and the lower and upper bounds for a point no view sees clear,
    None without ``smoke_colour``)."""
    stacked = np.concatenate([images.astype(np.float64), masks[..., None].astype(np.float64)], axis=-1)
    a = None if smoke_colour is None else np.asarray(smoke_colour, dtype=np.float64)[None]
    for ref, vs, us, seen_values, seen, clear in _views_of_masked_points(stacked, masks, depths, valid, viewmats,
                                                                         Ks, tolerance):
        n_clear = clear.sum(axis=0)
        own = images[ref, vs, us].astype(np.float64)
        surface = (seen_values[..., :3] * clear[..., None]).sum(axis=0) / np.maximum(n_clear, 1)[:, None]
        step = own - surface
        if a is None:
            yield ref, vs, us, n_clear > 0, 1.0 / np.maximum(cube_reach(surface, step), 1e-12), None
            continue
        towards = a - surface
        span = (towards * towards).sum(axis=1)
        alpha_clear = np.where(span > 1e-6, (step * towards).sum(axis=1) / np.maximum(span, 1e-6), 0.0)
        alpha_upper = 1.0 - 1.0 / np.maximum(cube_reach(np.broadcast_to(a, own.shape), own - a), 1e-12)
        reach_seen = (np.linalg.norm(seen_values[..., :3] - a[None], axis=-1) * seen).max(axis=0)
        alpha_lower = 1.0 - np.linalg.norm(own - a, axis=1) / np.maximum(reach_seen, 1e-12)
        yield ref, vs, us, n_clear > 0, alpha_clear, (alpha_lower, alpha_upper)


def estimated_dense(masks: np.ndarray, images: np.ndarray, depths: np.ndarray, valid: np.ndarray,
                    viewmats: np.ndarray, Ks: np.ndarray, smoke_colour: np.ndarray | None, floor: float,
                    tolerance: float = DEPTH_TOLERANCE) -> np.ndarray:
    """(frames, H, W) bool: masked pixels whose smoke, read off the images, may reach ``floor``
    (the module docstring gives the rule). ``images`` (frames, H, W, 3) are the smoky training
    frames in [0, 1]; ``smoke_colour`` where the haze lines meet, None where they do not; the rest
    as for ``never_seen_clear``."""
    out = (masks > 0.5) & ~valid
    for ref, vs, us, pinned, alpha_clear, bounds in _alpha_estimates(masks, images, depths, valid, viewmats, Ks,
                                                                     smoke_colour, tolerance):
        dense_unpinned = np.zeros(len(vs), dtype=bool) if bounds is None else 0.5 * (bounds[0] + bounds[1]) >= floor
        out[ref, vs, us] = np.where(pinned, alpha_clear >= floor, dense_unpinned)
    return out


def estimated_alpha_bound(masks: np.ndarray, images: np.ndarray, depths: np.ndarray, valid: np.ndarray,
                          viewmats: np.ndarray, Ks: np.ndarray, smoke_colour: np.ndarray | None, uncovered: float,
                          tolerance: float = DEPTH_TOLERANCE) -> np.ndarray:
    """(frames, H, W) in [0, 1]: the smoke alpha the images prove at each masked pixel, the target the
    mask term pushes up to with ``loss.mask_floor_where=estimated-bound`` (a continuous floor in place
    of the step at ``loss.mask_alpha_floor``). A point seen clear elsewhere: the alpha read off that
    view (exact with the smoke colour, a lower bound without). A point no view sees clear: the lower
    bound of its alpha (as if its clearest view were clear) where the haze lines meet, else 0: nothing
    is proven. Masked pixels the geometry does not cover: ``uncovered`` (the step's floor, as there).
    Unmasked pixels: 0."""
    out = np.where((masks > 0.5) & ~valid, float(uncovered), 0.0)
    for ref, vs, us, pinned, alpha_clear, bounds in _alpha_estimates(masks, images, depths, valid, viewmats, Ks,
                                                                     smoke_colour, tolerance):
        unpinned = np.zeros(len(vs)) if bounds is None else bounds[0]
        out[ref, vs, us] = np.clip(np.where(pinned, alpha_clear, unpinned), 0.0, 1.0)
    return out
