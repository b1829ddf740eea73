"""Smoke motion: the Deformable-3DGS deformation MLP or per-Gaussian Fourier trajectories, and
SmokeSeer's bimodal temporal opacity."""
from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from torch import Tensor, nn

from smokeseer.config import DeformConfig


def positional_encoding(x: Tensor, frequencies: int) -> Tensor:
    """NeRF encoding [x, sin(2^k π x), cos(2^k π x)] for k < frequencies."""
    if frequencies == 0:
        return x
    freqs = (2.0 ** torch.arange(frequencies, dtype=x.dtype, device=x.device)) * math.pi
    xb = x[..., None] * freqs
    return torch.cat([x, torch.sin(xb).flatten(-2), torch.cos(xb).flatten(-2)], dim=-1)


class DeformNetwork(nn.Module):
    """MLP (γ(x), γ(t)) → Δx (and Δrotation, Δlog-scale when asked), with a skip connection
    that re-injects the input, as in Deformable 3DGS. SmokeSeer's public code predicts only
    position offsets for smoke; ``predict_rotation_scale`` enables the full Deformable-3DGS head
    (used by the deformable-3dgs baseline). The output layer starts at zero so training begins
    from the canonical Gaussians."""

    def __init__(self, cfg: DeformConfig, position_scale: float, device: torch.device) -> None:
        super().__init__()
        self.cfg = cfg
        self.position_scale = position_scale
        in_x = 3 * (1 + 2 * cfg.xyz_frequencies)
        in_t = 1 + 2 * cfg.t_frequencies
        self.in_dim = in_x + in_t
        layers = []
        for i in range(cfg.depth):
            d_in = self.in_dim if i == 0 else cfg.width
            if i == cfg.skip_layer:
                d_in += self.in_dim
            layers.append(nn.Linear(d_in, cfg.width, device=device))
        self.layers = nn.ModuleList(layers)
        self.out_dim = 3 + (7 if cfg.predict_rotation_scale else 0)
        self.head = nn.Linear(cfg.width, self.out_dim, device=device)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, means: Tensor, t: float, center: Tensor) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """Offsets for ``means`` at normalised time ``t``. Positions are encoded relative to the
        scene centre in units of the scene extent so the frequencies mean the same in any scene.
        The network sees detached canonical positions, as in Deformable 3DGS: the canonical means
        learn only through the offset they receive, not through the network's input."""
        x = (means.detach() - center) / self.position_scale
        tt = torch.full((means.shape[0], 1), float(t), dtype=means.dtype, device=means.device)
        inp = torch.cat([positional_encoding(x, self.cfg.xyz_frequencies),
                         positional_encoding(tt, self.cfg.t_frequencies)], dim=-1)
        h = inp
        for i, layer in enumerate(self.layers):
            if i == self.cfg.skip_layer:
                h = torch.cat([inp, h], dim=-1)
            h = torch.relu_(layer(h))  # in place: the layer's output is not kept for its backward
        out = self.head(h)
        d_xyz = out[:, :3] * self.position_scale
        if not self.cfg.predict_rotation_scale:
            return d_xyz, None, None
        return d_xyz, out[:, 3:7], out[:, 7:10]


MOTION_KEYS: tuple[str, ...] = ("motion_means", "motion_quats", "motion_log_scales")
"""The per-Gaussian coefficients of ``deform.kind=fourier``, named for the tensor they offset."""


def fourier_bases(t: float, terms: int, like: Tensor) -> Tensor:
    """[1 + 2·terms] values at normalised time ``t``: t, then sin(kπt), cos(kπt) for k = 1..terms.
    Frequencies rise linearly (the slowest half-period spans the sequence), not by octaves as the
    MLP's encoding does: a Gaussian's own trajectory is fitted from the few dozen frames it is seen
    in, where octave frequencies would alias between them."""
    k = torch.arange(1, terms + 1, dtype=like.dtype, device=like.device) * (math.pi * float(t))
    return torch.cat([like.new_full((1,), float(t)), torch.sin(k), torch.cos(k)])


def motion_tensors(n: int, cfg: DeformConfig, device: torch.device) -> dict[str, Tensor]:
    """Zero coefficients for ``n`` Gaussians (no motion until trained): position offsets, and with
    ``cfg.predict_rotation_scale`` quaternion and log-scale offsets as the MLP's full head predicts."""
    shapes = {"motion_means": 3, "motion_quats": 4, "motion_log_scales": 3}
    keys = MOTION_KEYS if cfg.predict_rotation_scale else MOTION_KEYS[:1]
    return {k: torch.zeros((n, 1 + 2 * cfg.fourier_terms, shapes[k]), device=device) for k in keys}


def motion_offsets(params: Mapping[str, Tensor], t: float) -> tuple[Tensor, Tensor | None, Tensor | None]:
    """Each Gaussian's offsets at time ``t`` from its own coefficients (``motion_tensors``), in
    the order the MLP returns them. Position coefficients are in scene units. Costs a few
    multiply-adds per Gaussian, where the standard MLP costs about 10^5."""
    coeffs = params["motion_means"]
    phi = fourier_bases(t, (coeffs.shape[1] - 1) // 2, coeffs)
    d_xyz = torch.einsum("nbc,b->nc", coeffs, phi)
    if "motion_quats" not in params:
        return d_xyz, None, None
    return (d_xyz, torch.einsum("nbc,b->nc", params["motion_quats"], phi),
            torch.einsum("nbc,b->nc", params["motion_log_scales"], phi))


def temporal_opacity(t: float, t_lo: Tensor, t_hi: Tensor, log_sigma: Tensor) -> Tensor:
    """Bimodal temporal opacity: 1 between the two learned centres, a Gaussian fall-off outside.

    Centres are used in sorted order so an optimiser step that crosses them stays valid.
    """
    lo = torch.minimum(t_lo, t_hi)
    hi = torch.maximum(t_lo, t_hi)
    sigma = log_sigma.exp().clamp_min(1e-4)
    before = torch.relu(lo - t)
    after = torch.relu(t - hi)
    gap = before + after
    return torch.exp(-0.5 * (gap / sigma) ** 2)
