"""stage3.surface_colour_hold: each step on a surface Gaussian's colour scaled by its rate, after
the optimiser has taken it. Checked against torch's own Adam: rate 1 is its step to the bit, rate 0
no step, and between them the straight line; the moments are Adam's in every case, so a colour
that is released later steps as Adam would. The per-Gaussian share reads a map over the views a
centre lands in (smoky_share's mean, or clearest_view's least, what the hold reads), refreshed
when the count changes."""
from __future__ import annotations

import numpy as np
import torch

from smokeseer.model.gaussians import GaussianSet
from smokeseer.model.optim import Adam
from smokeseer.train.stage3 import ViewShare, hold_steps
from smokeseer.train.surface_union import clearest_view


def _colours(seed: int) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return {"sh_dc": torch.randn(4, 1, 3, generator=gen).requires_grad_(),
            "sh_rest": torch.randn(4, 3, 3, generator=gen).requires_grad_()}


def test_the_hold_scales_each_gaussians_step_and_leaves_adams_moments_alone() -> None:
    held, plain = _colours(0), _colours(0)
    ours = Adam([{"params": [t], "name": k} for k, t in held.items()], lr=0.01)
    ref = torch.optim.Adam([{"params": [t]} for t in plain.values()], lr=0.01)
    rate = torch.tensor([0.0, 0.25, 1.0, 0.5])
    for step in range(3):
        gen = torch.Generator().manual_seed(10 + step)
        grads = {k: torch.randn(t.shape, generator=gen) for k, t in held.items()}
        before = {k: t.detach().clone() for k, t in held.items()}
        for k in held:
            held[k].grad, plain[k].grad = grads[k].clone(), grads[k].clone()
        ours.step()
        ref_before = {k: t.detach().clone() for k, t in plain.items()}
        ref.step()
        taken = {k: held[k].detach() - before[k] for k in held}
        hold_steps(held, before, rate)
        for k in held:
            r = rate.view(-1, *([1] * (before[k].dim() - 1)))
            torch.testing.assert_close(held[k].detach(), before[k] + r * taken[k], rtol=0, atol=1e-7)
            if step == 0:  # the same start: rate 1 is torch's Adam step to the bit, rate 0 none
                torch.testing.assert_close(held[k].detach()[2], plain[k].detach()[2], rtol=0, atol=0)
                assert torch.equal(held[k].detach()[0], ref_before[k][0])
    for k in held:  # the moments saw every gradient in full
        torch.testing.assert_close(ours.state[held[k]]["exp_avg"], ref.state[plain[k]]["exp_avg"], rtol=0, atol=0)
        torch.testing.assert_close(ours.state[held[k]]["exp_avg_sq"], ref.state[plain[k]]["exp_avg_sq"],
                                   rtol=0, atol=0)


def test_the_share_is_the_maps_mean_or_least_over_the_views_a_centre_lands_in() -> None:
    """Two cameras looking along +z, 20 px focal length, 20 x 20 px: a point on the axis lands on
    column 10 of camera 0 and column 8 of camera 1 (moved +0.5 along x; depth 5), row 10 in both; a point far
    to the side lands in neither and reads 1. After a densification the share is recomputed."""
    K = np.array([[20.0, 0, 10], [0, 20.0, 10], [0, 0, 1]])
    v0, v1 = np.eye(4), np.eye(4)
    v1[0, 3] = -0.5
    maps = np.zeros((2, 20, 20), dtype=np.float32)
    maps[0, 10, 10], maps[1, 10, 8] = 0.8, 0.2
    share = ViewShare(maps, np.stack([v0, v1]), np.stack([K, K]))

    def surface(points: list[list[float]]) -> GaussianSet:
        n = len(points)
        return GaussianSet({"means": torch.tensor(points, dtype=torch.float32), "quats": torch.eye(4)[:1].repeat(n, 1),
                            "log_scales": torch.zeros(n, 3), "opacity": torch.zeros(n, 1)})

    got = share.at(1, surface([[0.0, 0.0, 5.0], [50.0, 0.0, 5.0]]))
    torch.testing.assert_close(got, torch.tensor([0.5, 1.0]))
    clearest = ViewShare(maps, np.stack([v0, v1]), np.stack([K, K]), reduce=clearest_view)
    torch.testing.assert_close(clearest.at(1, surface([[0.0, 0.0, 5.0], [50.0, 0.0, 5.0]])), torch.tensor([0.2, 1.0]))
    again = share.at(2, surface([[0.0, 0.0, 5.0], [50.0, 0.0, 5.0], [0.0, 0.0, 5.0]]))
    assert again.shape == (3,)
