"""smokeseer.model.optim.Adam against torch.optim.Adam: same bytes, interchangeable state dicts, and no
torch._dynamo import (the reason it exists)."""
from __future__ import annotations

import copy
import subprocess
import sys

import pytest
import torch

from smokeseer.model.optim import Adam


def _params(seed: int) -> list[torch.nn.Parameter]:
    g = torch.Generator().manual_seed(seed)
    return [torch.nn.Parameter(torch.randn(40, 3, generator=g)), torch.nn.Parameter(torch.randn(7, generator=g))]


def _groups(params: list[torch.nn.Parameter]) -> list[dict]:
    return [{"params": [params[0]], "lr": 0.05, "name": "means"}, {"params": [params[1]], "lr": 0.01, "name": "o"}]


def _train(opt, params: list[torch.nn.Parameter], steps: range, seed: int) -> None:
    """Steps with varying gradients, a learning-rate change and a step where one group has no gradient."""
    g = torch.Generator().manual_seed(seed)
    for i in steps:
        for k, p in enumerate(params):
            if not (i == 3 and k == 1):
                p.grad = torch.randn(p.shape, generator=g) * 10.0 ** (-k)
        if i == 5:
            opt.param_groups[0]["lr"] *= 0.5
        opt.step()
        opt.zero_grad(set_to_none=True)


@pytest.mark.parametrize("fused", [True, None])
def test_steps_equal_torch_adam_bit_for_bit(fused: bool | None) -> None:
    ours, ref = _params(0), _params(0)
    kwargs = {"lr": 0.0, "eps": 1e-15, "fused": fused}
    _train(Adam(_groups(ours), **kwargs), ours, range(12), 1)
    _train(torch.optim.Adam(_groups(ref), **kwargs), ref, range(12), 1)
    for a, b in zip(ours, ref):
        assert torch.equal(a, b)


@pytest.mark.parametrize("fused", [True, None])
def test_state_dicts_load_both_ways(fused: bool | None) -> None:
    ref = _params(2)
    torch_opt = torch.optim.Adam(_groups(ref), lr=0.0, eps=1e-15, fused=fused)
    _train(torch_opt, ref, range(4), 3)
    ours = [torch.nn.Parameter(p.detach().clone()) for p in ref]
    mine = Adam(_groups(ours), lr=0.0, eps=1e-15, fused=fused)
    mine.load_state_dict(torch_opt.state_dict())
    _train(torch_opt, ref, range(4, 9), 4)
    _train(mine, ours, range(4, 9), 4)
    for a, b in zip(ours, ref):
        assert torch.equal(a, b)
    back = [torch.nn.Parameter(p.detach().clone()) for p in ours]
    torch_again = torch.optim.Adam(_groups(back), lr=0.0, eps=1e-15, fused=fused)
    torch_again.load_state_dict(copy.deepcopy(mine.state_dict()))  # torch keeps the tensors it is given
    _train(torch_again, back, range(9, 12), 5)
    _train(mine, ours, range(9, 12), 5)
    for a, b in zip(ours, back):
        assert torch.equal(a, b)


def test_loaded_moments_are_copies() -> None:
    params = _params(6)
    opt = Adam(_groups(params), fused=True)
    _train(opt, params, range(2), 7)
    saved = opt.state_dict()
    other = Adam(_groups([torch.nn.Parameter(p.detach().clone()) for p in params]), fused=True)
    other.load_state_dict(saved)
    saved["state"][0]["exp_avg"].add_(1.0)
    assert not torch.equal(next(iter(other.state.values()))["exp_avg"], saved["state"][0]["exp_avg"])


def test_mismatched_state_dict_is_refused() -> None:
    opt = Adam(_groups(_params(8)))
    with pytest.raises(ValueError, match="different number"):
        opt.load_state_dict({"state": {}, "param_groups": [{"params": [0], "lr": 0.1}]})


def test_no_dynamo_import() -> None:
    code = ("import sys, torch\nfrom smokeseer.model.optim import Adam\n"
            "p = torch.nn.Parameter(torch.zeros(3))\nfor fused in (True, None):\n"
            "    o = Adam([p], fused=fused)\n    p.grad = torch.ones(3)\n    o.step()\n    o.zero_grad()\n"
            "    o.load_state_dict(o.state_dict())\n"
            "print('torch._dynamo' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"
