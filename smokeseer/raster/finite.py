"""Which of several tensors holds a NaN or Inf, found with one host sync in the common case (used by
the rasterizer's input check and the training loop's NaN guard).

Why fused: one vectorised 2-norm per tensor (``_foreach_norm``; NaN and Inf propagate into it)
and a single sync replace one ``isfinite().all()`` and sync per tensor, about ten times less
CPU on the demo's training state (benchmarks/iteration_parts.py). Only a norm that is not finite
pays for the exact per-tensor test; a finite tensor whose norm overflows passes it.
"""
from __future__ import annotations

from typing import Iterable

import torch


def first_non_finite(named: Iterable[tuple[str, torch.Tensor | None]]) -> str | None:
    """The name of the first tensor with a NaN or Inf, or None (non-float and empty tensors and
    None entries are finite by definition)."""
    checked = [(name, t.detach()) for name, t in named if t is not None and t.numel() and t.is_floating_point()]
    if not checked:
        return None
    norms = torch._foreach_norm([t for _, t in checked], 2)
    if len({n.dtype for n in norms}) > 1:
        norms = [n.double() for n in norms]
    if bool(torch.isfinite(torch.stack(norms)).all()):
        return None
    return next((name for name, t in checked if not bool(torch.isfinite(t).all())), None)
