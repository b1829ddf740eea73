"""Stage 3's surface from both Stage 2s where the smoke is thin (``stage3.surface_init=by-smoke-colour``).

A Stage 2 on the smoky RGB frames (RGB-only's) holds the surface at the RGB's resolution where
the smoke is thin, and bakes the smoke into floaters where it is not. The thermal Stage 2 sees
through the smoke but is as coarse as its 80×60 frames. An RGB Gaussian whose centre lies well
in front of the thermal surface in most training views that see it is smoke taken for surface,
and is carved away. Only the thermal Gaussians that fall in the carved RGB surface's holes join
it: where the RGB sees the surface, the coarse thermal Gaussians (their RGB colour borrowed from
a neighbour) would blur it, and Stage 3 would start far below RGB-only's. Each set takes the
other's colour from its nearest neighbour in the other set.

How much of the RGB Stage 2 is believed follows the haze-line trust t and where the images say
the smoke is dense (the mask floor's reading, ``smokeseer.train.mask_floor.estimated_dense``):
each RGB Gaussian keeps 1 − t × (the share of the views seeing its centre in which that pixel
reads dense) of its opacity. Under dense absorbing smoke everywhere (room) the thermal Stage 2
all but stands alone; under a dense plume over part of a scene the RGB Stage 2 stays where the
smoke is thin; and a small change in what the images say moves the start a little.
"""
from __future__ import annotations

from collections.abc import Iterator
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
from smokeseer.stage1.haze_lines import SmokeColourEstimate
from smokeseer.train.depth_prior import DepthPriorMaps, rendered_depth_prior
from smokeseer.train.stage2 import Stage2Result, train_stage2, views_of
from smokeseer.train.util import RunContext


FILL_OPAQUE_SHARE = 0.5
"""A thermal Gaussian is left out when the carved RGB surface is opaque (alpha > 0.5) where its
centre lands in more than this share of the RGB training views that see it."""


def surface_start(colour: SmokeColourEstimate | None, smoke: bool) -> tuple[float, str]:
    """The haze-line trust that fades the RGB Stage 2 where the smoke reads dense (0: it is kept
    whole), and the note saying why. Without smoke Gaussians (``smoke`` false) the RGB sees the
    surface everywhere."""
    if not smoke:
        return 0.0, ("surface from the RGB Stage 2 and the thermal Gaussians in its holes (stage3.surface_init="
                     "by-smoke-colour): the run has no smoke, so the RGB sees the surface")
    trust = 0.0 if colour is None or colour.colour is None else colour.trust
    return trust, ("surface from the RGB Stage 2, each Gaussian at 1 − trust × (its share of views reading dense "
                   "smoke) of its opacity, and the thermal Gaussians in its holes (stage3.surface_init="
                   f"by-smoke-colour): haze-line trust {trust:.3f}")


def view_share(means: np.ndarray, marked: np.ndarray, viewmats: np.ndarray, Ks: np.ndarray) -> np.ndarray:
    """Per point: the share of the views whose image its centre lands in where it lands on a
    ``marked`` pixel ((views, H, W) bool at the cameras ``viewmats``, ``Ks``); 0 where no view sees it."""
    seen = np.zeros(len(means), dtype=np.int64)
    hits = np.zeros_like(seen)
    for f, idx, iu, iv, _ in _landings(means, viewmats, Ks, marked.shape):
        seen[idx] += 1
        hits[idx[marked[f, iv, iu]]] += 1
    return hits / np.maximum(seen, 1)


def fade(g: GaussianSet, shares: Tensor) -> GaussianSet:
    """A copy of ``g`` with each opacity scaled by its share in (0, 1]."""
    tensors = {k: v.detach().clone() for k, v in g.state_dict().items()}
    o, s = tensors["opacity"].double(), shares.double()
    log_on = torch.nn.functional.logsigmoid(o)
    # logit(s σ(o)) = log s + log σ(o) − log(σ(−o) + (1 − s) σ(o)), exact at s = 1 and for opaque o
    off = torch.logaddexp(torch.nn.functional.logsigmoid(-o), torch.log1p(-s) + log_on)
    tensors["opacity"] = (torch.log(s) + log_on - off).to(tensors["opacity"].dtype)
    return GaussianSet(tensors)


@dataclass
class CarveResult:
    """Which RGB Gaussians stay, and how many training views saw each one in front of the thermal surface."""

    keep: np.ndarray
    seen: np.ndarray
    in_front: np.ndarray


def _landings(means: np.ndarray, viewmats: np.ndarray, Ks: np.ndarray, shape: tuple[int, ...]
              ) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Per training view ``f`` of maps shaped ``shape`` (views, height, width): the indices of the
    points whose centre lands in the image, their pixel columns and rows, and their depths."""
    n_frames, height, width = shape
    for f in range(n_frames):
        inside, iu, iv, z = pixels_of(means, viewmats[f], Ks[f], width, height)
        idx = np.nonzero(inside)[0]
        yield f, idx, iu, iv, z[idx]


def carve_in_front(means: np.ndarray, depths: np.ndarray, valid: np.ndarray, viewmats: np.ndarray,
                   Ks: np.ndarray, tolerance: float) -> CarveResult:
    """A Gaussian is carved when, in more than half of the training views where its centre lands on
    the thermal surface's valid pixels (``depths``/``valid``: that surface rendered at the cameras
    ``viewmats``, ``Ks``), it is nearer than (1 − ``tolerance``) × that surface's depth. Gaussians
    no view checks (sky, outside the thermal model's cover) stay."""
    seen = np.zeros(len(means), dtype=np.int64)
    in_front = np.zeros_like(seen)
    for f, idx, iu, iv, z in _landings(means, viewmats, Ks, depths.shape):
        checked = valid[f, iv, iu]
        seen[idx[checked]] += 1
        in_front[idx[checked][z[checked] < (1.0 - tolerance) * depths[f, iv[checked], iu[checked]]]] += 1
    return CarveResult(~(2 * in_front > seen), seen, in_front)


def in_holes(means: np.ndarray, opaque: np.ndarray, viewmats: np.ndarray, Ks: np.ndarray,
             share: float) -> np.ndarray:
    """Which points to keep: those whose centre lands on a pixel where ``opaque`` (the carved RGB
    surface's alpha > 0.5 at each training camera) holds in at most ``share`` of the views that see
    the centre. Points no view sees are kept."""
    seen = np.zeros(len(means), dtype=np.int64)
    covered = np.zeros_like(seen)
    for f, idx, iu, iv, _ in _landings(means, viewmats, Ks, opaque.shape):
        seen[idx] += 1
        covered[idx[opaque[f, iv, iu]]] += 1
    return ~(covered > share * seen)


def _nearest(source: Tensor, target: Tensor) -> Tensor:
    """Index into ``source`` of each ``target`` point's nearest neighbour."""
    _, idx = cKDTree(source.detach().cpu().numpy()).query(target.detach().cpu().numpy(), k=1)
    return torch.as_tensor(idx, dtype=torch.long, device=target.device)


def union_surface(thermal: GaussianSet, rgb: GaussianSet, keep: Tensor, thermal_keep: Tensor,
                  sh_degree: int) -> GaussianSet:
    """The thermal Gaussians ``thermal_keep`` (RGB colour from the nearest kept RGB Gaussian) and the
    kept RGB Gaussians ``keep`` (thermal value from the nearest of all thermal Gaussians), one
    shared opacity each."""
    full = {k: v.detach() for k, v in thermal.state_dict().items()}
    th = {k: v[thermal_keep].clone() for k, v in full.items()}
    kept = {k: v.detach()[keep].clone() for k, v in rgb.state_dict().items()}
    if len(kept["means"]) == 0:
        add_rgb_sh(th, sh_degree)
        return GaussianSet(th)
    near_rgb = _nearest(kept["means"], th["means"])
    th["sh_dc"] = kept["sh_dc"][near_rgb].clone()
    th["sh_rest"] = torch.zeros_like(kept["sh_rest"][near_rgb])
    kept["thermal"] = full["thermal"][_nearest(full["means"], kept["means"])].clone()
    return GaussianSet({k: torch.cat([th[k], kept[k]]) for k in th})


@dataclass
class TwoSurfaces:
    """Stage 3's joined surface, the RGB Stage 2 it came from, and what the carving did."""

    surface: GaussianSet
    rgb: Stage2Result
    record: dict[str, Any]

    def describe(self) -> str:
        r = self.record
        return (f"surface from both Stage 2s: the {r['thermal_kept']} of {r['thermal']} thermal Gaussians in the RGB "
                f"surface's holes + {r['rgb_kept']} of {r['rgb']} RGB Gaussians (trust {r['trust']:.3f}: "
                f"{r['rgb_faded_out']} faded under opacity {r['prune_opacity']:g} left out, mean opacity share "
                f"{r['rgb_opacity_share']:.3f}; {r['rgb'] - r['rgb_faded_out'] - r['rgb_kept']} in front of the thermal "
                f"surface carved, tolerance {r['tolerance']:g}; {r['rgb_unchecked']} no view could check kept)")


def join_surfaces(ctx: RunContext, rgb: ModalityData, init_points: np.ndarray, thermal: Stage2Result,
                  thermal_depth: DepthPriorMaps, trust: float, dense: np.ndarray | None) -> TwoSurfaces:
    """Train RGB-only's Stage 2 (checkpoint ``stage2_rgb``, keyed as RGB-only's Stage 2 is), fade
    each Gaussian to 1 − ``trust`` × its share of the training views where ``dense`` (the RGB
    training frames' pixels whose smoke reads dense; None: every pixel) marks its centre, leave out
    those faded under the surface's prune opacity (its first densification would prune them),
    carve the rest with the thermal surface's depth at the RGB training cameras
    (``thermal_depth``), and join it with the thermal Gaussians in the carved surface's holes."""
    cfg = ctx.cfg
    rgb_s2 = train_stage2(ctx, rgb, init_points, deformable=False, checkpoint="stage2_rgb",
                          sha=replace(cfg, mode="rgb-only").stage2_sha256())
    means = rgb_s2.gaussians["means"].detach().cpu().numpy().astype(np.float64)
    cameras = rgb.cameras("train")
    dense_share = (np.zeros(len(means)) if trust == 0.0 else np.ones(len(means)) if dense is None
                   else view_share(means, dense, *cameras))
    dev = rgb_s2.gaussians["means"].device
    shares = torch.as_tensor(1.0 - trust * dense_share, dtype=torch.float32, device=dev)
    prune = cfg.stage3.surface_densify.prune_opacity
    bright = (shares * torch.sigmoid(rgb_s2.gaussians["opacity"].detach()) >= prune).cpu().numpy()
    idx = torch.as_tensor(np.nonzero(bright)[0], device=dev)
    rgb_set = fade(GaussianSet({k: v.detach()[idx] for k, v in rgb_s2.gaussians.state_dict().items()}), shares[idx])
    carve = carve_in_front(means[bright], thermal_depth.maps.cpu().numpy(), thermal_depth.valid.cpu().numpy(),
                           *cameras, cfg.stage3.carve_tolerance)
    keep = torch.as_tensor(carve.keep, device=dev)
    carved = GaussianSet({k: v.detach()[keep] for k, v in rgb_set.state_dict().items()})
    opaque = rendered_depth_prior(carved, views_of(rgb, rgb.indices("train"), dev), "rgb").valid.cpu().numpy()
    holes = in_holes(thermal.gaussians["means"].detach().cpu().numpy().astype(np.float64), opaque,
                     *cameras, FILL_OPAQUE_SHARE)
    thermal_keep = torch.as_tensor(holes, device=dev)
    surface = union_surface(thermal.gaussians, rgb_set, keep, thermal_keep, cfg.sh_degree)
    record = {"thermal": thermal.gaussians.n, "rgb": rgb_s2.gaussians.n, "trust": trust,
              "rgb_opacity_share": round(float(shares.mean()), 4), "rgb_faded_out": int((~bright).sum()),
              "prune_opacity": prune, "rgb_kept": int(carve.keep.sum()),
              "rgb_unchecked": int((carve.seen == 0).sum()), "tolerance": cfg.stage3.carve_tolerance,
              "thermal_kept": int(holes.sum()), "fill_opaque_share": FILL_OPAQUE_SHARE}
    return TwoSurfaces(surface, rgb_s2, record)
