"""The smoke colour anchored to the haze-line estimate by its trust: the blend's ends are the two
methods it replaces (held at trust 1, learned at 0), and in between the learned part moves the
colour by exactly (1 − trust) of what it would move it alone."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from smokeseer.model.scene import SceneModel, SmokeAnchor, make_smoke

ESTIMATE = torch.tensor([0.2, 0.25, 0.3])


def _model(trust: float | None) -> SceneModel:
    rng = np.random.default_rng(0)
    smoke = make_smoke(rng.uniform(-1, 1, (40, 3)), 0.1, 1.0, 1.0, rng, torch.device("cpu"))
    smoke.params["color"].data = torch.as_tensor(rng.normal(0, 1, (40, 3)), dtype=torch.float32)
    anchor = None if trust is None else SmokeAnchor(ESTIMATE, trust)
    return SceneModel(smoke, smoke, None, True, torch.zeros(3), 0, smoke_anchor=anchor)


def _grad(model: SceneModel, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    model.smoke.params["color"].grad = None
    colours = model.smoke_colours()
    ((colours - target) ** 2).sum().backward()
    return colours.detach(), model.smoke.params["color"].grad.clone()


@pytest.mark.parametrize("trust", [0.0, 0.3, 0.97, 1.0])
def test_the_blend_and_its_gradient_scale_with_one_minus_the_trust(trust: float) -> None:
    target = torch.linspace(0.0, 1.0, 120).reshape(40, 3)
    free = _model(None)
    own = torch.sigmoid(free.smoke["color"]).detach()
    anchored = _model(trust)
    colours, grad = _grad(anchored, target)
    torch.testing.assert_close(colours, trust * ESTIMATE + (1 - trust) * own)
    # d colour / d param = (1 - trust) sigmoid'; the loss's own gradient is taken at the blended colour
    expected = 2 * (colours - target) * (1 - trust) * own * (1 - own)
    torch.testing.assert_close(grad, expected, rtol=1e-5, atol=1e-7)


def test_full_trust_holds_the_colour_exactly_and_gives_no_gradient() -> None:
    colours, grad = _grad(_model(1.0), torch.zeros(40, 3))
    torch.testing.assert_close(colours, ESTIMATE.expand(40, 3), rtol=0, atol=0)
    assert torch.count_nonzero(grad) == 0


def test_no_anchor_is_the_papers_learned_colour() -> None:
    free = _model(None)
    torch.testing.assert_close(free.smoke_colours(), torch.sigmoid(free.smoke["color"]), rtol=0, atol=0)
    with pytest.raises(ValueError, match="no smoke Gaussians"):
        SceneModel(free.surface, None, None, True, torch.zeros(3), 0).smoke_colours()
