"""Real spherical harmonics (degrees 0-3) in the 3DGS / gsplat basis and sign convention.

The basis for band ``l`` is ordered m = -l..l and carries the Condon-Shortley phase, which is what
3DGS checkpoints assume (band 1 is ``(-y, z, -x) * C1``). ``eval_sh`` returns the raw SH sum; the
rasterizer adds 0.5 and clamps at 0 as 3DGS does, so that degree-0 coefficients of 0 mean grey.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

# Normalisation constants of the real SH basis functions, written from their closed forms.
_C0 = 0.5 * math.sqrt(1.0 / math.pi)
_C1 = math.sqrt(3.0 / (4.0 * math.pi))
_C2_XY = 0.5 * math.sqrt(15.0 / math.pi)
_C2_Z = 0.25 * math.sqrt(5.0 / math.pi)
_C2_XX = 0.25 * math.sqrt(15.0 / math.pi)
_C3_A = 0.25 * math.sqrt(35.0 / (2.0 * math.pi))
_C3_B = 0.5 * math.sqrt(105.0 / math.pi)
_C3_C = 0.25 * math.sqrt(21.0 / (2.0 * math.pi))
_C3_D = 0.25 * math.sqrt(7.0 / math.pi)
_C3_E = 0.25 * math.sqrt(105.0 / math.pi)


def num_sh_bases(degree: int) -> int:
    """Number of SH coefficients for a given degree: (degree + 1)^2."""
    return (degree + 1) ** 2


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """Evaluate the real SH basis functions at unit directions ``dirs`` [..., 3] -> [..., K]."""
    if not 0 <= degree <= 3:
        raise ValueError(f"sh_degree must be in 0..3, got {degree}")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, _C0)]
    if degree >= 1:
        out += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [
            _C2_XY * x * y,
            -_C2_XY * y * z,
            _C2_Z * (2.0 * zz - xx - yy),
            -_C2_XY * x * z,
            _C2_XX * (xx - yy),
        ]
    if degree >= 3:
        out += [
            -_C3_A * y * (3.0 * xx - yy),
            _C3_B * x * y * z,
            -_C3_C * y * (4.0 * zz - xx - yy),
            _C3_D * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            -_C3_C * x * (4.0 * zz - xx - yy),
            _C3_E * z * (xx - yy),
            -_C3_A * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def sh_basis_along(degree: int, dirs: Tensor) -> Tensor:
    """The SH basis [..., K] along directions ``dirs`` [..., 3] that need not be unit length (they
    are normalised; a zero direction gives the DC term only)."""
    norm = torch.linalg.vector_norm(dirs, dim=-1, keepdim=True)
    return sh_basis(degree, dirs / norm.clamp_min(torch.finfo(dirs.dtype).tiny ** 0.5))


def sh_sum(basis: Tensor, coeffs: Tensor) -> Tensor:
    """Sum SH coefficients ``coeffs`` [..., K', D] (K' >= K) weighted by ``basis`` [..., K] -> [..., D]."""
    k = basis.shape[-1]
    if coeffs.shape[-2] < k:
        raise ValueError(f"coeffs has {coeffs.shape[-2]} SH bases, the basis has {k}")
    return (basis.unsqueeze(-1) * coeffs[..., :k, :]).sum(dim=-2)


def eval_sh(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Sum SH coefficients ``coeffs`` [..., K, D] along directions ``dirs`` [..., 3] -> [..., D].

    Directions need not be unit length (they are normalised; a zero direction gives the DC term
    only). Only the first (degree+1)^2 coefficients are used, so a degree can be raised during
    training without reallocating.
    """
    k = num_sh_bases(degree)
    if coeffs.shape[-2] < k:
        raise ValueError(f"coeffs has {coeffs.shape[-2]} SH bases, degree {degree} needs {k}")
    return sh_sum(sh_basis_along(degree, dirs), coeffs)
