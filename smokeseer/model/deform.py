"""Smoke motion: the Deformable-3DGS deformation MLP or per-Gaussian Fourier trajectories (the
plane field is ``smokeseer.model.planes``), and SmokeSeer's bimodal temporal opacity.

The two fields share one interface: ``field(means, t, center)`` gives the offsets at time ``t``,
and ``field.decode(field.encode(means, center), t)`` gives the same offsets with the part that does
not depend on time (``encode``) computed once for any number of times: Stage 3 evaluates the smoke
at the RGB frame's time and at the thermal frame's (``deform.shared_position``)."""
from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from torch import Tensor, nn

from smokeseer.config import DeformConfig

Offsets = tuple[Tensor, Tensor | None, Tensor | None]
"""Position offsets (scene units), and quaternion and log-scale offsets where the head predicts them."""
Encoded = tuple[Tensor, ...]
"""A field's time-independent part, one row per Gaussian in every tensor (``rows`` selects alike)."""


def positional_encoding(x: Tensor, frequencies: int) -> Tensor:
    """NeRF encoding [x, sin(2^k π x), cos(2^k π x)] for k < frequencies."""
    if frequencies == 0:
        return x
    freqs = (2.0 ** torch.arange(frequencies, dtype=x.dtype, device=x.device)) * math.pi
    xb = x[..., None] * freqs
    return torch.cat([x, torch.sin(xb).flatten(-2), torch.cos(xb).flatten(-2)], dim=-1)


def split_offsets(out: Tensor, position_scale: float, full: bool) -> Offsets:
    """A head's output as (Δx in scene units, Δrotation, Δlog-scale); the last two only for ``full``."""
    d_xyz = out[:, :3] * position_scale
    if not full:
        return d_xyz, None, None
    return d_xyz, out[:, 3:7], out[:, 7:10]


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
        self.in_x = 3 * (1 + 2 * cfg.xyz_frequencies)
        in_t = 1 + 2 * cfg.t_frequencies
        self.in_dim = self.in_x + in_t
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

    def _inputs(self, means: Tensor, center: Tensor) -> Tensor:
        """γ of the positions relative to the scene centre in units of the scene extent, so the
        frequencies mean the same in any scene. Detached canonical positions, as in Deformable
        3DGS: the canonical means learn only through the offset they receive, not through the
        network's input."""
        return positional_encoding((means.detach() - center) / self.position_scale, self.cfg.xyz_frequencies)

    def _time(self, t: float, like: Tensor) -> Tensor:
        return positional_encoding(like.new_full((1, 1), float(t)), self.cfg.t_frequencies)

    def forward(self, means: Tensor, t: float, center: Tensor) -> Offsets:
        """Offsets for ``means`` at normalised time ``t``."""
        gx = self._inputs(means, center)
        inp = torch.cat([gx, self._time(t, gx).expand(means.shape[0], -1)], dim=-1)
        h = inp
        for i, layer in enumerate(self.layers):
            if i == self.cfg.skip_layer:
                h = torch.cat([inp, h], dim=-1)
            h = torch.relu_(layer(h))  # in place: the layer's output is not kept for its backward
        return split_offsets(self.head(h), self.position_scale, self.cfg.predict_rotation_scale)

    def _blocks(self, i: int) -> tuple[Tensor, Tensor, Tensor | None]:
        """Layer ``i``'s weight split by what it multiplies: (γ(x) columns, γ(t) columns, hidden
        columns). Layer 0 and the skip layer see the input (layer 0 twice when the skip is at 0:
        its blocks are summed); the hidden columns come after it."""
        w = self.layers[i].weight
        n_inp = int(i == 0) + int(i == self.cfg.skip_layer)
        starts = [k * self.in_dim for k in range(n_inp)]
        wx = sum(w[:, a:a + self.in_x] for a in starts)
        wt = sum(w[:, a + self.in_x:a + self.in_dim] for a in starts)
        return wx, wt, (w[:, n_inp * self.in_dim:] if i > 0 else None)

    def encode(self, means: Tensor, center: Tensor) -> Encoded:
        """γ(x) times the γ(x) columns of the first layer and of the skip layer, [N, 2·width]
        (the first layer's alone when the skip is at layer 0): the per-Gaussian products that do
        not depend on time."""
        layers = sorted({0, self.cfg.skip_layer})
        return (self._inputs(means, center) @ torch.cat([self._blocks(i)[0] for i in layers]).t(),)

    def decode(self, encoded: Encoded, t: float) -> Offsets:
        """The offsets at time ``t`` from ``encode``'s products. γ(t) is the same for every
        Gaussian, so its columns add one vector (with the bias) to a layer's output instead of a
        product per Gaussian; only the hidden layers run per Gaussian."""
        pos = encoded[0]
        gt = self._time(t, pos)
        w = self.cfg.width
        h = pos
        for i, layer in enumerate(self.layers):
            if i == 0 or i == self.cfg.skip_layer:
                _, wt, wh = self._blocks(i)
                shift = torch.addmm(layer.bias, gt, wt.t())
                h = pos[:, :w] + shift if i == 0 else torch.addmm(shift, h, wh.t()) + pos[:, w:]
            else:
                h = layer(h)
            h = torch.relu_(h)
        return split_offsets(self.head(h), self.position_scale, self.cfg.predict_rotation_scale)


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
