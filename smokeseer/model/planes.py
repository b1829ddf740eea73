"""``deform.kind=planes``: the smoke's motion as a factorised space-time feature field (the
HexPlane / K-Planes shape 4DGS uses), with the deformation MLP's interface
(``smokeseer.model.deform``).

Six planes of features over (x,y), (x,z), (y,z), (x,t), (y,t), (z,t), at ``planes_levels`` spatial
resolutions, stored [3, H, W, features] (features contiguous). On the CPU the lookups run in a
compiled kernel (``smokeseer/model/csrc/plane_features.cpp``): torch's ``grid_sample`` spends
about ten times as long, most of it in its backward scatter; on other devices they are
``grid_sample`` itself, which the tests also hold the kernel to.
"""
from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from smokeseer.config import DeformConfig
from smokeseer.model.deform import Encoded, Offsets, split_offsets
from smokeseer.raster.extension import Kernel, load_kernel

PLANE_FEATURES = Kernel("smokeseer_plane_features", "the CPU plane-field lookups",
                        (Path(__file__).resolve().parent / "csrc" / "plane_features.cpp",), (),
                        "or set deform.kind to mlp or fourier")
"""The compiled lookups, built as the rasterizer is (``scripts/install.sh`` builds both)."""

SPACE_PAIRS = [[0, 1], [0, 2], [1, 2]]
"""The coordinates of the (x,y), (x,z) and (y,z) planes, in grid order (along W, along H)."""


class _PlaneProduct(torch.autograd.Function):
    """The compiled product of three bilinear plane lookups; gradient with respect to the planes
    only (the field reads detached positions)."""

    @staticmethod
    def forward(ctx: torch.autograd.function.FunctionCtx, planes: Tensor, coords: Tensor) -> Tensor:
        ctx.save_for_backward(planes, coords)
        return load_kernel(PLANE_FEATURES).plane_product_forward(planes, coords)

    @staticmethod
    def backward(ctx: torch.autograd.function.FunctionCtx, grad: Tensor) -> tuple[Tensor, None]:
        planes, coords = ctx.saved_tensors
        return load_kernel(PLANE_FEATURES).plane_product_backward(grad.contiguous(), planes, coords), None


def plane_product_reference(planes: Tensor, coords: Tensor) -> Tensor:
    """``plane_product`` through torch's ``grid_sample``: the path off the CPU, and the kernel's reference."""
    v = F.grid_sample(planes.permute(0, 3, 1, 2), coords.transpose(0, 1)[:, :, None, :], mode="bilinear",
                      padding_mode="border", align_corners=True)
    return (v[0] * v[1] * v[2])[..., 0].t()


def plane_product(planes: Tensor, coords: Tensor) -> Tensor:
    """The product over three planes [3, H, W, F] of their bilinear values at ``coords`` [N, 3, 2]
    (per plane, x along W and y along H in [-1, 1], -1 and 1 on the centres of the outer cells;
    outside, clamped to them), [N, F]."""
    if planes.device.type == "cpu":
        return _PlaneProduct.apply(planes.contiguous(), coords.contiguous())
    return plane_product_reference(planes, coords)


def total_variation(plane: Tensor) -> Tensor:
    """Mean squared difference of neighbouring cells along H and along W of planes [..., H, W, F], summed."""
    return (((plane[..., 1:, :, :] - plane[..., :-1, :, :]) ** 2).mean()
            + ((plane[..., :, 1:, :] - plane[..., :, :-1, :]) ** 2).mean())


def time_curvature(plane: Tensor) -> Tensor:
    """Mean squared second difference along H (time, in a space-time plane [3, T, W, F])."""
    return ((plane[..., 2:, :, :] - 2 * plane[..., 1:-1, :, :] + plane[..., :-2, :, :]) ** 2).mean()


class PlaneField(nn.Module):
    """Six feature planes read bilinearly, then a head (one hidden ReLU layer) giving the offsets
    the MLP gives, in units of the scene extent as the MLP's are. Per Gaussian a few dozen memory
    reads replace the MLP's matrix products.

    The planes' features are multiplied (K-Planes' Hadamard product) and the levels concatenated.
    Why a product and not a sum: a sum makes each feature a sum of functions of two coordinates,
    which a small head cannot turn into motion that depends on where and when together; a
    product of a spatial feature and a time feature can, and with the space-time planes starting
    at 1 the field starts as a static spatial field that learns its time dependence (K-Planes
    found the product better). The spatial planes start uniform in [0.1, 0.5] (K-Planes), the
    head's output layer at zero, so the offsets start at zero.

    Positions are mapped to [-1, 1] over ``lo``..``hi`` (the smoke's domain, kept with the
    weights), time over [0, 1]. A point outside the domain reads the border of each plane (its
    coordinates clamped): its offset is that of the nearest point on the domain's boundary."""

    def __init__(self, cfg: DeformConfig, lo: Tensor, hi: Tensor, position_scale: float,
                 device: torch.device) -> None:
        super().__init__()
        self.cfg = cfg
        self.position_scale = position_scale
        self.register_buffer("lo", lo.detach().to(device=device, dtype=torch.float32).clone())
        self.register_buffer("hi", hi.detach().to(device=device, dtype=torch.float32).clone())
        f, t_res = cfg.planes_features, cfg.planes_time_resolution
        res = [cfg.planes_resolution * 2 ** level for level in range(cfg.planes_levels)]
        self.space = nn.ParameterList(nn.Parameter(torch.empty(3, r, r, f, device=device).uniform_(0.1, 0.5))
                                      for r in res)
        self.time = nn.ParameterList(nn.Parameter(torch.ones(3, t_res, r, f, device=device)) for r in res)
        self.hidden = nn.Linear(f * cfg.planes_levels, cfg.planes_head_width, device=device)
        self.head = nn.Linear(cfg.planes_head_width, 3 + (7 if cfg.predict_rotation_scale else 0), device=device)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def coordinates(self, means: Tensor) -> Tensor:
        """Detached positions (as the MLP sees them) in [-1, 1] over the domain; outside it they
        are left as they are, and the lookups clamp them."""
        return 2.0 * (means.detach() - self.lo) / (self.hi - self.lo) - 1.0

    def encode(self, means: Tensor, center: Tensor | None = None) -> Encoded:
        """(Coordinates [N, 3], the product of the three spatial planes' features [N, levels ×
        features]): the lookups that do not depend on time. ``center`` is unused: the planes
        carry their own domain."""
        u = self.coordinates(means)
        coords = u[:, SPACE_PAIRS]
        return u, torch.cat([plane_product(p, coords) for p in self.space], dim=1)

    def decode(self, encoded: Encoded, t: float) -> Offsets:
        u, spatial = encoded
        coords = torch.stack([u, u.new_full(u.shape, 2.0 * float(t) - 1.0)], dim=2)
        features = spatial * torch.cat([plane_product(p, coords) for p in self.time], dim=1)
        out = self.head(torch.relu_(self.hidden(features)))
        return split_offsets(out, self.position_scale, self.cfg.predict_rotation_scale)

    def forward(self, means: Tensor, t: float, center: Tensor | None = None) -> Offsets:
        return self.decode(self.encode(means, center), t)

    def smoothness(self) -> tuple[Tensor, Tensor]:
        """(Total variation averaged over every plane, both axes; the space-time planes' squared
        second difference along time, averaged.) Both 0 on constant planes."""
        tv = torch.stack([total_variation(p) for p in (*self.space, *self.time)]).mean()
        curve = torch.stack([time_curvature(p) for p in self.time]).mean()
        return tv, curve

    def parameter_groups(self, lr: float) -> list[dict]:
        """Adam groups: the planes at ``planes_lr_scale`` × the head's rate (``lr_scale`` is kept
        in the group so the stage's decay keeps the ratio)."""
        scale = self.cfg.planes_lr_scale
        return [{"params": [*self.space, *self.time], "lr": lr * scale, "lr_scale": scale},
                {"params": [*self.hidden.parameters(), *self.head.parameters()], "lr": lr, "lr_scale": 1.0}]
