"""Pluggable depth priors for Stage 3's depth-consistency loss.

A prior gives, per training frame of one camera (``camera``: the thermal camera, as in the
paper, or the RGB camera), a map plus a validity mask, and says whether the map is depth or
inverse depth (monocular networks predict relative disparity). The loss aligns it
to the render with a per-image scale and shift, so only the prior's shape matters.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from smokeseer.model.gaussians import GaussianSet
from smokeseer.model.scene import View, place_static, render_depth


@dataclass
class DepthPriorMaps:
    """Prior maps for one camera's training frames, in the order the trainer indexes them."""

    maps: Tensor
    valid: Tensor
    space: str
    camera: str = "rgb"


def rendered_depth_prior(geometry: GaussianSet, views: list[View], camera: str) -> DepthPriorMaps:
    """Default prior, needing no weights: expected depth of the Stage 2 model rendered from the
    ``camera``'s training views (thermal geometry is not hidden by smoke). Pixels the model
    barely covers (alpha < 0.5) are left out. Stage 3 keeps training the surface geometry, and
    RGB smoke can pull it off; this anchors it to the geometry thermal alone gave."""
    maps, valid = [], []
    with torch.no_grad():
        placed = place_static(geometry)
        opac = torch.sigmoid(geometry["opacity"])
        for v in views:
            out = render_depth(v, placed, opac)
            maps.append(out.depths[0, ..., 0])
            valid.append((out.alphas[0, ..., 0] > 0.5) & (out.depths[0, ..., 0] > 0))
    return DepthPriorMaps(torch.stack(maps), torch.stack(valid), "depth", camera)


def monocular_depth_prior(weights: Path, images: Tensor, camera: str) -> DepthPriorMaps:
    """Optional prior from a TorchScript monocular model on local disk (e.g. an exported
    Depth Anything / MiDaS). It maps [1, 3, H, W] images in [0, 1] to relative inverse depth
    [1, H, W] or [1, 1, H, W]; single-channel thermal frames are repeated to three channels, as
    the paper feeds thermal images to its monocular model. Nothing is downloaded."""
    weights = Path(weights)
    if not weights.is_file():
        raise ValueError(f"mono_weights: no TorchScript file at {weights}")
    model = torch.jit.load(str(weights), map_location="cpu").eval()
    maps = []
    with torch.no_grad():
        for img in images:
            chw = img.permute(2, 0, 1)
            pred = model((chw.expand(3, -1, -1) if chw.shape[0] == 1 else chw)[None].float().cpu())
            pred = pred.reshape(pred.shape[-2], pred.shape[-1])
            if pred.shape != img.shape[:2]:
                pred = torch.nn.functional.interpolate(pred[None, None], size=img.shape[:2], mode="bilinear",
                                                       align_corners=False)[0, 0]
            maps.append(pred.to(images.device))
    stacked = torch.stack(maps)
    return DepthPriorMaps(stacked, torch.isfinite(stacked) & (stacked > 0), "disparity", camera)


def file_depth_prior(inverse: Tensor, camera: str) -> DepthPriorMaps:
    """The dataset's own maps (the official layout's ``images_depth``), inverse depth with 0 where
    there is none; compared as inverse depth, as the official code does."""
    return DepthPriorMaps(inverse, inverse > 0, "disparity", camera)
