"""Stage 3's surface from both Stage 2s: the thermal geometry plus the RGB Gaussians it does not
contradict.

A Stage 2 on the smoky RGB frames (RGB-only's) holds the surface at the RGB's resolution where
the smoke is thin, and bakes the smoke into floaters where it is not. The thermal Stage 2 sees
through the smoke but is as coarse as its 80×60 frames. An RGB Gaussian whose centre lies well
in front of the thermal surface in most training views that see it is smoke taken for surface,
and is carved away; the rest join the thermal Gaussians, each set taking the other's colour from
its nearest neighbour in the other set.

Under dense smoke the RGB Stage 2 puts most of its Gaussians behind the thermal surface, not in
front, so carving alone keeps them (room: 14k of 26k). What gives it away is the RGB's own depth:
rendered at the training cameras, it lies in front of the thermal surface wherever the smoke
hides that surface. With ``stage3.agree_tolerance`` an RGB Gaussian stays only where, in most
views, the two Stage 2s' depths agree at its pixel: there the RGB saw the surface.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from scenes.scene import ModalityData
from scenes.cameras import pixels_of
from smokeseer.model.gaussians import GaussianSet
from smokeseer.model.scene import add_rgb_sh
from smokeseer.train.depth_prior import DepthPriorMaps, rendered_depth_prior
from smokeseer.train.stage2 import Stage2Result, train_stage2, views_of
from smokeseer.train.util import RunContext


@dataclass
class CarveResult:
    """Which RGB Gaussians stay; per Gaussian, how many training views checked it, saw it in front
    of the thermal surface, and saw it where the two Stage 2s' depths agree."""

    keep: np.ndarray
    seen: np.ndarray
    in_front: np.ndarray
    agreeing: np.ndarray


def depths_agree(rgb_depths: np.ndarray, rgb_valid: np.ndarray, depths: np.ndarray, valid: np.ndarray,
                 tolerance: float) -> np.ndarray:
    """(frames, H, W) bool: pixels both Stage 2s cover where the RGB's rendered depth is within
    ``tolerance`` × the thermal surface's depth of it."""
    return rgb_valid & valid & (np.abs(rgb_depths - depths) <= tolerance * depths)


def carve_in_front(means: np.ndarray, depths: np.ndarray, valid: np.ndarray, viewmats: np.ndarray,
                   Ks: np.ndarray, tolerance: float, agree: np.ndarray | None = None) -> CarveResult:
    """A Gaussian is carved when, in more than half of the training views where its centre lands on
    the thermal surface's valid pixels (``depths``/``valid``: that surface rendered at the cameras
    ``viewmats``, ``Ks``), it is nearer than (1 − ``tolerance``) × that surface's depth. With
    ``agree`` (``depths_agree``), it is also carved unless more than half of those views put it on
    an agreeing pixel. Gaussians no view checks (sky, outside the thermal model's cover) stay."""
    seen = np.zeros(len(means), dtype=np.int64)
    in_front = np.zeros_like(seen)
    agreeing = np.zeros_like(seen)
    n_frames, height, width = depths.shape
    for f in range(n_frames):
        inside, iu, iv, z = pixels_of(means, viewmats[f], Ks[f], width, height)
        checked = valid[f, iv, iu]
        idx = np.nonzero(inside)[0][checked]
        seen[idx] += 1
        in_front[idx[z[idx] < (1.0 - tolerance) * depths[f, iv[checked], iu[checked]]]] += 1
        if agree is not None:
            agreeing[idx[agree[f, iv[checked], iu[checked]]]] += 1
    keep = ~(2 * in_front > seen)
    if agree is not None:
        keep &= (seen == 0) | (2 * agreeing > seen)
    return CarveResult(keep, seen, in_front, agreeing)


COLOUR_REACH = 3.0
"""A thermal Gaussian takes an RGB Gaussian's colour only if that one lies within this many of its
largest standard deviations: the same patch of surface. Farther (room: a median 37 of them, where
the gate keeps few RGB Gaussians) the colour would belong to another surface, so it starts grey,
as with the thermal surface alone."""


def _nearest(source: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """Index into ``source`` of each ``target`` point's nearest neighbour, and its distance."""
    dist, idx = cKDTree(source.detach().cpu().numpy()).query(target.detach().cpu().numpy(), k=1)
    return (torch.as_tensor(idx, dtype=torch.long, device=target.device),
            torch.as_tensor(dist, dtype=target.dtype, device=target.device))


def union_surface(thermal: GaussianSet, rgb: GaussianSet, keep: Tensor, sh_degree: int) -> GaussianSet:
    """The thermal Gaussians (RGB colour from the nearest kept RGB Gaussian within
    ``COLOUR_REACH`` standard deviations, else grey) and the kept RGB Gaussians (thermal value from
    the nearest thermal Gaussian), one shared opacity each."""
    th = {k: v.detach().clone() for k, v in thermal.state_dict().items()}
    kept = {k: v.detach()[keep].clone() for k, v in rgb.state_dict().items()}
    add_rgb_sh(th, sh_degree)
    if len(kept["means"]) == 0:
        return GaussianSet(th)
    near_rgb, dist = _nearest(kept["means"], th["means"])
    close = dist < COLOUR_REACH * th["log_scales"].exp().amax(dim=1)
    th["sh_dc"][close] = kept["sh_dc"][near_rgb[close]]
    kept["thermal"] = th["thermal"][_nearest(th["means"], kept["means"])[0]].clone()
    return GaussianSet({k: torch.cat([th[k], kept[k]]) for k in th})


@dataclass
class TwoSurfaces:
    """Stage 3's joined surface, the RGB Stage 2 it came from, and what the carving did."""

    surface: GaussianSet
    rgb: Stage2Result
    record: dict[str, Any]

    def describe(self) -> str:
        r = self.record
        return (f"surface from both Stage 2s: {r['thermal']} thermal + {r['rgb_kept']} of {r['rgb']} RGB Gaussians "
                f"({r['rgb_in_front']} in front of the thermal surface carved, tolerance {r['tolerance']:g}"
                + ("" if r["agreeing_pixels"] is None else
                   f"; {r['rgb'] - r['rgb_kept'] - r['rgb_in_front']} more off the pixels where the two Stage 2s' "
                   f"depths agree within {r['agree_tolerance']:g} ({100 * r['agreeing_pixels']:.0f} % of the "
                   "thermal surface's)")
                + f"; {r['rgb_unchecked']} no view could check kept)")


def join_surfaces(ctx: RunContext, rgb: ModalityData, init_points: np.ndarray, thermal: Stage2Result,
                  thermal_depth: DepthPriorMaps) -> TwoSurfaces:
    """Train RGB-only's Stage 2 (checkpoint ``stage2_rgb``, keyed as RGB-only's Stage 2 is), carve it
    with the thermal surface's depth at the RGB training cameras (``thermal_depth``) and, with
    ``stage3.agree_tolerance``, with where the two depths agree; join the sets."""
    cfg = ctx.cfg
    rgb_s2 = train_stage2(ctx, rgb, init_points, deformable=False, checkpoint="stage2_rgb",
                          sha=replace(cfg, mode="rgb-only").stage2_sha256())
    depths, valid = thermal_depth.maps.cpu().numpy(), thermal_depth.valid.cpu().numpy()
    agree = None
    if cfg.stage3.agree_tolerance > 0:
        own = rendered_depth_prior(rgb_s2.gaussians, views_of(rgb, rgb.indices("train"), thermal_depth.maps.device),
                                   "rgb")
        agree = depths_agree(own.maps.cpu().numpy(), own.valid.cpu().numpy(), depths, valid,
                             cfg.stage3.agree_tolerance)
    carve = carve_in_front(rgb_s2.gaussians["means"].detach().cpu().numpy().astype(np.float64), depths, valid,
                           *rgb.cameras("train"), cfg.stage3.carve_tolerance, agree)
    keep = torch.as_tensor(carve.keep, device=rgb_s2.gaussians["means"].device)
    surface = union_surface(thermal.gaussians, rgb_s2.gaussians, keep, cfg.sh_degree)
    record = {"thermal": thermal.gaussians.n, "rgb": rgb_s2.gaussians.n, "rgb_kept": int(carve.keep.sum()),
              "rgb_unchecked": int((carve.seen == 0).sum()), "tolerance": cfg.stage3.carve_tolerance,
              "rgb_in_front": int((2 * carve.in_front > carve.seen).sum()),
              "agree_tolerance": cfg.stage3.agree_tolerance,
              "agreeing_pixels": None if agree is None else round(float(agree.sum() / max(int(valid.sum()), 1)), 4)}
    return TwoSurfaces(surface, rgb_s2, record)
