"""EWA projection of 3D Gaussians to screen-space conics (3DGS / gsplat semantics).

The 2D covariance is built as A A^T with A = J W R S (2x3), so its determinant comes from the
Cauchy-Binet identity |A_0 x A_1|^2. That value is never negative, which keeps needle-like and
near-singular Gaussians finite where the textbook ``a*c - b^2`` cancels catastrophically.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

EPS2D = 0.3  # low-pass dilation added to the 2D covariance diagonal, in px^2 (3DGS, gsplat)
SIGMA_EXTENT = 3.0  # pixel rectangle half-width in standard deviations of the major axis


@dataclass
class Projection:
    """Per-(camera, Gaussian) screen-space quantities; culled entries hold finite dummies."""

    means2d: Tensor  # [C, N, 2] pixel coordinates
    conics: Tensor  # [C, N, 3] inverse 2D covariance (a, b, c) of [[a, b], [b, c]]
    depths: Tensor  # [C, N] view-space z
    radii: Tensor  # [C, N] float pixel radius (0 where culled)
    visible: Tensor  # [C, N] bool
    sort_depths: Tensor | None = None  # [C, N] float64 view z where available (sort key without float32 ties)

    def sort_key(self) -> Tensor:
        """Front-to-back sort key: the float64 depths where kept, so two Gaussians whose float32
        depths round to the same value keep their true order."""
        return self.sort_depths if self.sort_depths is not None else self.depths.detach()


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """(w, x, y, z) quaternions [N, 4], any non-zero norm, to rotation matrices [N, 3, 3]."""
    q = quats / torch.linalg.vector_norm(quats, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(*quats.shape[:-1], 3, 3)


def project_gaussians(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
) -> Projection:
    """Project N Gaussians into C pinhole cameras with the 3DGS local-affine (EWA) approximation.

    The Jacobian uses the view-frustum clamp of 3DGS (1.3x the half field of view), so Gaussians
    far off-screen do not produce huge, useless footprints; the centre itself is not clamped.

    Evaluated in float64 and returned in the input dtype, as the compiled projection does: in
    float32 the rotation gradient of an isotropic Gaussian (truly zero) comes out as ~1e-7
    rounding noise, which Adam (eps 1e-15) turns into full-size random steps.
    """
    dtype = means.dtype
    wide = torch.promote_types(dtype, torch.float64)
    means, quats, scales = means.to(wide), quats.to(wide), scales.to(wide)
    viewmats, Ks = viewmats.to(wide), Ks.to(wide)
    rot_w2c = viewmats[:, :3, :3]
    trans = viewmats[:, :3, 3]
    means_c = torch.einsum("cij,nj->cni", rot_w2c, means) + trans[:, None, :]
    x, y, z = means_c.unbind(-1)
    in_depth = (z >= near_plane) & (z <= far_plane)
    z_safe = torch.where(in_depth, z, torch.ones_like(z))

    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    u = x / z_safe
    v = y / z_safe
    u_lim = torch.minimum(torch.maximum(u, -(cx / fx + 0.3 * tan_fovx)), (width - cx) / fx + 0.3 * tan_fovx)
    v_lim = torch.minimum(torch.maximum(v, -(cy / fy + 0.3 * tan_fovy)), (height - cy) / fy + 0.3 * tan_fovy)

    # M = W R S: columns of the Gaussian's principal axes, scaled, in camera space.
    rs = quat_to_rotmat(quats) * scales[:, None, :]
    m = torch.einsum("cij,njk->cnik", rot_w2c, rs)
    inv_z = 1.0 / z_safe
    a0 = (fx * inv_z)[..., None] * (m[..., 0, :] - u_lim[..., None] * m[..., 2, :])
    a1 = (fy * inv_z)[..., None] * (m[..., 1, :] - v_lim[..., None] * m[..., 2, :])
    cov_a = (a0 * a0).sum(-1)
    cov_b = (a0 * a1).sum(-1)
    cov_c = (a1 * a1).sum(-1)
    det0 = (torch.linalg.cross(a0, a1) ** 2).sum(-1)
    det = det0 + EPS2D * (cov_a + cov_c) + EPS2D * EPS2D
    conics = torch.stack([(cov_c + EPS2D) / det, -cov_b / det, (cov_a + EPS2D) / det], dim=-1)

    half_diff = 0.5 * (cov_a - cov_c)
    lam_max = 0.5 * (cov_a + cov_c) + EPS2D + torch.sqrt(torch.clamp_min(half_diff * half_diff + cov_b * cov_b, 0.01))
    radius = torch.ceil(SIGMA_EXTENT * torch.sqrt(lam_max.detach()))

    means2d = torch.stack([fx * u + cx, fy * v + cy], dim=-1)
    mx, my = means2d.detach().unbind(-1)
    on_screen = (mx + radius > 0) & (mx - radius < width) & (my + radius > 0) & (my - radius < height)
    visible = in_depth & on_screen & torch.isfinite(radius)
    zero = torch.zeros((), dtype=wide, device=means.device)
    return Projection(
        means2d=torch.where(visible[..., None], means2d, zero).to(dtype),
        conics=torch.where(visible[..., None], conics, zero).to(dtype),
        depths=z.to(dtype),
        radii=torch.where(visible, radius, zero).to(dtype),
        visible=visible,
        sort_depths=z.detach(),
    )
