"""Adam for the trainer, without ``torch.optim.Optimizer``.

Why: every ``torch.optim.Optimizer`` method is wrapped in ``torch._disable_dynamo``, whose first
call imports ``torch._dynamo`` (1.7-2 s on this 2-core machine, 3 % of a quick demo run) for
nothing: the trainer never compiles. This class keeps the same parameter groups, per-parameter
state and ``state_dict`` layout, and steps through ``torch.optim.adam.adam``, the functional that
``torch.optim.Adam.step`` itself calls with the same arguments, so the updates are the same bytes
(``tests/test_smokeseer_optim.py``) and checkpoints written by either class load in both.
"""
from __future__ import annotations

from typing import Any, Iterable

import torch
from torch import Tensor
from torch.optim.adam import adam

_FIXED = ("params",)


class Adam:
    """Adam (no weight decay, no amsgrad) over groups of leaf tensors; ``fused=True`` uses the
    one-kernel-per-tensor step, ``None`` lets torch pick its default (single-tensor on CPU)."""

    def __init__(self, params: Iterable[Tensor] | Iterable[dict[str, Any]], lr: float = 1e-3,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8, fused: bool | None = None) -> None:
        items = list(params)
        groups = items if items and isinstance(items[0], dict) else [{"params": items}]
        defaults = {"lr": lr, "betas": betas, "eps": eps, "fused": fused}
        self.param_groups: list[dict[str, Any]] = [{**defaults, **g, "params": list(g["params"])} for g in groups]
        self.state: dict[Tensor, dict[str, Tensor]] = {}

    def _moments(self, p: Tensor, fused: bool | None) -> dict[str, Tensor]:
        """The parameter's state, created on first use as torch.optim.Adam creates it (the step
        counter is a float32 scalar, on the parameter's device when fused)."""
        state = self.state.get(p)
        if state is None:
            step_dtype = torch.float32 if fused or torch.get_default_dtype() != torch.float64 else torch.float64
            state = self.state[p] = {
                "step": torch.zeros((), dtype=step_dtype, device=p.device if fused else "cpu"),
                "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
                "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format),
            }
        return state

    @torch.no_grad()
    def step(self) -> None:
        """One Adam update of every parameter that has a gradient."""
        for group in self.param_groups:
            params = [p for p in group["params"] if p.grad is not None]
            if not params:
                continue
            states = [self._moments(p, group["fused"]) for p in params]
            beta1, beta2 = group["betas"]
            adam(params, [p.grad for p in params], [s["exp_avg"] for s in states],
                 [s["exp_avg_sq"] for s in states], [], [s["step"] for s in states],
                 foreach=None, capturable=False, differentiable=False, fused=group["fused"], grad_scale=None,
                 found_inf=None, has_complex=False, decoupled_weight_decay=False, amsgrad=False,
                 beta1=beta1, beta2=beta2, lr=group["lr"], weight_decay=0.0, eps=group["eps"], maximize=False)

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Drop (or zero) every parameter's gradient."""
        for group in self.param_groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                if set_to_none:
                    p.grad = None
                else:
                    p.grad.zero_()

    def state_dict(self) -> dict[str, Any]:
        """torch.optim's layout: state by parameter index, groups listing their indices. The
        tensors are the live ones (a checkpoint serialises them, a snapshot clones them)."""
        index: dict[Tensor, int] = {}
        groups = []
        for group in self.param_groups:
            ids = []
            for p in group["params"]:
                ids.append(index.setdefault(p, len(index)))
            groups.append({**{k: v for k, v in group.items() if k not in _FIXED}, "params": ids})
        state = {index[p]: dict(s) for p, s in self.state.items() if p in index}
        return {"state": state, "param_groups": groups}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Restore hyperparameters and moments saved by this class or by torch.optim.Adam,
        matching parameters by position as torch does."""
        saved_groups = state_dict["param_groups"]
        if len(saved_groups) != len(self.param_groups) or any(
                len(s["params"]) != len(g["params"]) for s, g in zip(saved_groups, self.param_groups)):
            raise ValueError("loaded state dict has a different number of parameter groups or parameters")
        self.state = {}
        for group, saved in zip(self.param_groups, saved_groups):
            group.update({k: v for k, v in saved.items() if k not in _FIXED})
            fused = group.get("fused")
            for p, i in zip(group["params"], saved["params"]):
                s = state_dict["state"].get(i)
                if s is None:
                    continue
                self.state[p] = {
                    "step": s["step"].to(device=p.device if fused else "cpu", copy=True),
                    **{k: s[k].to(device=p.device, dtype=p.dtype, copy=True) for k in ("exp_avg", "exp_avg_sq")},
                }
