"""Stage 3's surface from both Stage 2s where the smoke is thin (``stage3.surface_init=by-smoke-colour``).

A Stage 2 on the smoky RGB frames (RGB-only's) holds the surface at the RGB's resolution where
the smoke is thin, and bakes the smoke into floaters where it is not. The thermal Stage 2 sees
through the smoke but is as coarse as its 80×60 frames. An RGB Gaussian whose centre lies well
in front of the thermal surface in most training views that see it is smoke taken for surface,
and is carved away. Only the thermal Gaussians that fall in the carved RGB surface's holes join
it: where the RGB sees the surface, the coarse thermal Gaussians (their RGB colour borrowed from
a neighbour) would blur it, and Stage 3 would start far below RGB-only's. Each set takes the
other's colour from its nearest neighbour in the other set.

How much the RGB Stage 2 is believed follows the haze-line estimate's surface trust t
(``surface_start``; ``SmokeColourEstimate.surface_trust``): its opacities are scaled by 1 − t
before the carving, and under dense absorbing smoke (t = 1) the thermal Stage 2 stands alone.
Scaling the whole set, not the Gaussians where the smoke reads dense, was chosen on the
validation views: the local fade lost 3.6 dB on machine
(docs/experiments/2026-12-02-haze-line-trust.md).
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


SHARE_FLOOR = 1e-3
"""The least opacity share a faded Gaussian keeps, so that its logit stays finite; at under 0.005
opacity it is pruned at the first densification step anyway."""
FILL_OPAQUE_SHARE = 0.5
"""A thermal Gaussian is left out when the carved RGB surface is opaque (alpha > 0.5) where its
centre lands in more than this share of the RGB training views that see it."""


def surface_start(colour: SmokeColourEstimate | None, smoke: bool) -> tuple[float, str]:
    """The share of its opacity each RGB Stage-2 Gaussian keeps in Stage 3's start (1 − the
    haze-line surface trust; 0: the thermal Stage 2 alone), and the note saying why. The trust is
    high for dense absorbing smoke, which the RGB Stage 2 takes for surface; without smoke Gaussians
    (``smoke`` false) the RGB sees the surface everywhere."""
    if not smoke:
        return 1.0, ("surface from the RGB Stage 2 and the thermal Gaussians in its holes (stage3.surface_init="
                     "by-smoke-colour): the run has no smoke, so the RGB sees the surface")
    trust = 0.0 if colour is None or colour.colour is None else colour.surface_trust
    if trust == 1.0:
        return 0.0, ("surface from the thermal Stage 2 alone (stage3.surface_init=by-smoke-colour): the haze "
                     "lines are fully trusted (dense, dark smoke), so the RGB Stage 2 would take the smoke for surface")
    return 1.0 - trust, (f"surface from the RGB Stage 2 at {1.0 - trust:.3f} × its opacities and the thermal Gaussians "
                         f"in its holes (stage3.surface_init=by-smoke-colour): haze-line surface trust {trust:.3f}, so the "
                         "RGB sees the surface through the smoke that far")


def fade(g: GaussianSet, share: float | np.ndarray) -> GaussianSet:
    """``g`` with its opacities scaled by ``share`` in (0, 1], one for all or one per Gaussian
    (held to at least ``SHARE_FLOOR``); a copy, or the same tensors when every share is 1."""
    if np.all(np.asarray(share) == 1.0):
        return g
    tensors = {k: v.detach().clone() for k, v in g.state_dict().items()}
    o = tensors["opacity"].double()
    s = torch.as_tensor(np.clip(share, SHARE_FLOOR, 1.0), dtype=torch.float64, device=o.device)
    s = s.reshape(-1, *([1] * (o.dim() - 1))) if s.dim() else s
    log_on = torch.nn.functional.logsigmoid(o)
    # logit(s σ(o)) = log s + log σ(o) − log(σ(−o) + (1 − s) σ(o)): finite for opaque o
    off = torch.logaddexp(torch.nn.functional.logsigmoid(-o), torch.log1p(-s) + log_on)
    tensors["opacity"] = (torch.log(s) + log_on - off).to(tensors["opacity"].dtype)
    return GaussianSet(tensors)


@dataclass
class CarveResult:
    """Which RGB Gaussians stay, how many training views check each one against the thermal surface
    and see it in front, and the share of the checking views in which it lies in front on a pixel
    marked smoke (Stage 1's mask summed there over ``seen``; 0 without masks or checks)."""

    keep: np.ndarray
    seen: np.ndarray
    in_front: np.ndarray
    smoky_in_front: np.ndarray


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
                   Ks: np.ndarray, tolerance: float, masks: np.ndarray | None = None) -> CarveResult:
    """A Gaussian is carved when, in more than half of the training views where its centre lands on
    the thermal surface's valid pixels (``depths``/``valid``: that surface rendered at the cameras
    ``viewmats``, ``Ks``), it is nearer than (1 − ``tolerance``) × that surface's depth. Gaussians
    no view checks (sky, outside the thermal model's cover) stay. With ``masks`` (Stage 1's smoke
    masks at the same cameras) the result also weighs each view in front by its mask there."""
    seen = np.zeros(len(means), dtype=np.int64)
    in_front = np.zeros_like(seen)
    smoky = np.zeros(len(means))
    for f, idx, iu, iv, z in _landings(means, viewmats, Ks, depths.shape):
        front = valid[f, iv, iu]
        seen[idx[front]] += 1
        front[front] = z[front] < (1.0 - tolerance) * depths[f, iv[front], iu[front]]
        in_front[idx[front]] += 1
        if masks is not None:
            smoky[idx[front]] += np.clip(masks[f, iv[front], iu[front]], 0.0, 1.0)
    return CarveResult(~(2 * in_front > seen), seen, in_front, smoky / np.maximum(seen, 1))


def smoky_share(means: np.ndarray, masks: np.ndarray, viewmats: np.ndarray, Ks: np.ndarray) -> np.ndarray:
    """Per point, the mean of the clipped mask (``masks``: Stage 1's smoke masks at the cameras
    ``viewmats``, ``Ks``) over the views whose image its centre lands in (no occlusion test: a point
    behind a nearer surface is taken to lie under the same smoke as that surface). Points no view
    sees get 1: only the thermal frames can tell anything about them."""
    seen = np.zeros(len(means))
    masked = np.zeros(len(means))
    for f, idx, iu, iv, _ in _landings(means, viewmats, Ks, masks.shape):
        seen[idx] += 1.0
        masked[idx] += np.clip(masks[f, iv, iu], 0.0, 1.0)
    return np.where(seen > 0, masked / np.maximum(seen, 1.0), 1.0)


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
        carved = (f"each faded by the share of its views that see it in front of the thermal surface on smoke, "
                  f"mean {r['rgb_carve_share']:.3g}" if r["carve_by"] == "depth-and-smoke"
                  else f"{r['rgb'] - r['rgb_kept']} in front of the thermal surface carved")
        return (f"surface from both Stage 2s: the {r['thermal_kept']} of {r['thermal']} thermal Gaussians in the RGB "
                f"surface's holes + {r['rgb_kept']} of {r['rgb']} RGB Gaussians at {r['rgb_opacity_share']:.3g} × "
                f"their opacities ({carved}, tolerance {r['tolerance']:g}; "
                f"{r['rgb_unchecked']} no view could check kept)")


def join_surfaces(ctx: RunContext, rgb: ModalityData, init_points: np.ndarray, thermal: Stage2Result,
                  thermal_depth: DepthPriorMaps, rgb_share: float) -> TwoSurfaces:
    """Train RGB-only's Stage 2 (checkpoint ``stage2_rgb``, keyed as RGB-only's Stage 2 is), scale
    its opacities by ``rgb_share`` (``surface_start``), carve it with the thermal surface's depth at
    the RGB training cameras (``thermal_depth``), and join it with the thermal Gaussians in the
    carved surface's holes."""
    cfg = ctx.cfg
    rgb_s2 = train_stage2(ctx, rgb, init_points, deformable=False, checkpoint="stage2_rgb",
                          sha=replace(cfg, mode="rgb-only").stage2_sha256())
    depths, valid = thermal_depth.maps.cpu().numpy(), thermal_depth.valid.cpu().numpy()
    means = rgb_s2.gaussians["means"].detach().cpu().numpy().astype(np.float64)
    masks = rgb.masks[rgb.indices("train")] if rgb.masks is not None else None
    share: float | np.ndarray = rgb_share
    by_smoke = cfg.stage3.carve_by == "depth-and-smoke"
    carve = carve_in_front(means, depths, valid, *rgb.cameras("train"), cfg.stage3.carve_tolerance,
                           masks if by_smoke else None)
    kept = np.ones(len(means), dtype=bool) if by_smoke else carve.keep
    if by_smoke:
        share = share * (1.0 - carve.smoky_in_front)
    rgb_set = fade(rgb_s2.gaussians, share)
    dev = rgb_set["means"].device
    keep = torch.as_tensor(kept, device=dev)
    carved = GaussianSet({k: v.detach()[keep] for k, v in rgb_set.state_dict().items()})
    opaque = rendered_depth_prior(carved, views_of(rgb, rgb.indices("train"), dev), "rgb").valid.cpu().numpy()
    holes = in_holes(thermal.gaussians["means"].detach().cpu().numpy().astype(np.float64), opaque,
                     *rgb.cameras("train"), FILL_OPAQUE_SHARE)
    thermal_keep = torch.as_tensor(holes, device=dev)
    surface = union_surface(thermal.gaussians, rgb_set, keep, thermal_keep, cfg.sh_degree)
    shares = np.broadcast_to(np.asarray(share, dtype=np.float64), (rgb_s2.gaussians.n,))
    record = {"thermal": thermal.gaussians.n, "rgb": rgb_s2.gaussians.n,
              "rgb_opacity_share": float(shares.mean()) if len(shares) else rgb_share,
              "rgb_opacity_share_quartiles": np.quantile(shares, [0.25, 0.5, 0.75]).round(4).tolist()
              if len(shares) else [],
              "rgb_kept": int(kept.sum()), "carve_by": cfg.stage3.carve_by,
              "rgb_carve_share": float(carve.smoky_in_front.mean()) if by_smoke and len(means) else 0.0,
              "rgb_unchecked": int((carve.seen == 0).sum()), "tolerance": cfg.stage3.carve_tolerance,
              "thermal_kept": int(holes.sum()), "fill_opaque_share": FILL_OPAQUE_SHARE}
    return TwoSurfaces(surface, rgb_s2, record)
