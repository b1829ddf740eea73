"""Stage 3's surface from both Stage 2s: the thermal geometry plus the RGB Gaussians it does not
contradict.

A Stage 2 on the smoky RGB frames (RGB-only's) holds the surface at the RGB's resolution where
the smoke is thin, and bakes the smoke into floaters where it is not. The thermal Stage 2 sees
through the smoke but is as coarse as its 80×60 frames. An RGB Gaussian whose centre lies well
in front of the thermal surface in most training views that see it is smoke taken for surface,
and is carved away; the rest join the thermal Gaussians, each set taking the other's colour from
its nearest neighbour in the other set.
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
from smokeseer.train.depth_prior import DepthPriorMaps
from smokeseer.train.stage2 import Stage2Result, train_stage2
from smokeseer.train.util import RunContext


@dataclass
class CarveResult:
    """Which RGB Gaussians stay, and how many training views saw each one in front of the thermal surface."""

    keep: np.ndarray
    seen: np.ndarray
    in_front: np.ndarray


def carve_in_front(means: np.ndarray, depths: np.ndarray, valid: np.ndarray, viewmats: np.ndarray,
                   Ks: np.ndarray, tolerance: float) -> CarveResult:
    """A Gaussian is carved when, in more than half of the training views where its centre lands on
    the thermal surface's valid pixels (``depths``/``valid``: that surface rendered at the cameras
    ``viewmats``, ``Ks``), it is nearer than (1 − ``tolerance``) × that surface's depth. Gaussians
    no view checks (sky, outside the thermal model's cover) stay."""
    seen = np.zeros(len(means), dtype=np.int64)
    in_front = np.zeros_like(seen)
    n_frames, height, width = depths.shape
    for f in range(n_frames):
        inside, iu, iv, z = pixels_of(means, viewmats[f], Ks[f], width, height)
        checked = valid[f, iv, iu]
        idx = np.nonzero(inside)[0][checked]
        seen[idx] += 1
        in_front[idx[z[idx] < (1.0 - tolerance) * depths[f, iv[checked], iu[checked]]]] += 1
    return CarveResult(~(2 * in_front > seen), seen, in_front)


def _nearest(source: Tensor, target: Tensor) -> Tensor:
    """Index into ``source`` of each ``target`` point's nearest neighbour."""
    _, idx = cKDTree(source.detach().cpu().numpy()).query(target.detach().cpu().numpy(), k=1)
    return torch.as_tensor(idx, dtype=torch.long, device=target.device)


def union_surface(thermal: GaussianSet, rgb: GaussianSet, keep: Tensor, sh_degree: int) -> GaussianSet:
    """The thermal Gaussians (RGB colour from the nearest kept RGB Gaussian) and the kept RGB
    Gaussians (thermal value from the nearest thermal Gaussian), one shared opacity each."""
    th = {k: v.detach().clone() for k, v in thermal.state_dict().items()}
    kept = {k: v.detach()[keep].clone() for k, v in rgb.state_dict().items()}
    if len(kept["means"]) == 0:
        add_rgb_sh(th, sh_degree)
        return GaussianSet(th)
    near_rgb = _nearest(kept["means"], th["means"])
    th["sh_dc"] = kept["sh_dc"][near_rgb].clone()
    th["sh_rest"] = torch.zeros_like(kept["sh_rest"][near_rgb])
    kept["thermal"] = th["thermal"][_nearest(th["means"], kept["means"])].clone()
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
                f"({r['rgb'] - r['rgb_kept']} in front of the thermal surface carved, tolerance {r['tolerance']:g}; "
                f"{r['rgb_unchecked']} no view could check kept)")


def join_surfaces(ctx: RunContext, rgb: ModalityData, init_points: np.ndarray, thermal: Stage2Result,
                  thermal_depth: DepthPriorMaps) -> TwoSurfaces:
    """Train RGB-only's Stage 2 (checkpoint ``stage2_rgb``, keyed as RGB-only's Stage 2 is), carve it
    with the thermal surface's depth at the RGB training cameras (``thermal_depth``), join the sets."""
    cfg = ctx.cfg
    rgb_s2 = train_stage2(ctx, rgb, init_points, deformable=False, checkpoint="stage2_rgb",
                          sha=replace(cfg, mode="rgb-only").stage2_sha256())
    carve = carve_in_front(rgb_s2.gaussians["means"].detach().cpu().numpy().astype(np.float64),
                           thermal_depth.maps.cpu().numpy(), thermal_depth.valid.cpu().numpy(), *rgb.cameras("train"),
                           cfg.stage3.carve_tolerance)
    keep = torch.as_tensor(carve.keep, device=rgb_s2.gaussians["means"].device)
    surface = union_surface(thermal.gaussians, rgb_s2.gaussians, keep, cfg.sh_degree)
    record = {"thermal": thermal.gaussians.n, "rgb": rgb_s2.gaussians.n, "rgb_kept": int(carve.keep.sum()),
              "rgb_unchecked": int((carve.seen == 0).sum()), "tolerance": cfg.stage3.carve_tolerance}
    return TwoSurfaces(surface, rgb_s2, record)
