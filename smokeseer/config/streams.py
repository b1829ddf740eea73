"""One random stream per consumer, each derived from the run seed and the stream's name.

Why: with one generator for everything, one extra Gaussian split (or one more initial point)
shifts every later draw, so the views a stage trains on depend on how densification went.
Each consumer draws from its own stream instead, so the view order is a function of the seed
alone, and the runs of two methods on one scene see the same RGB views in the same order.

The derivation: numpy's ``SeedSequence(entropy=seed, spawn_key=<the name's UTF-8 bytes>)``;
numpy streams are ``default_rng`` of it, torch streams a CPU ``torch.Generator`` seeded with
its first 64-bit word (``stream_seed``). The names (docs/method.md, "Random streams"):

- ``init.points.<modality>``: Stage 2's initial points in that modality's view
- ``init.smoke``, ``init.smoke.temporal``: the smoke Gaussians' initial points, their temporal opacities
- ``stage1.pose-noise``: the pose-noise study's perturbations
- ``stage1.haze-lines``: the pixels the haze-line estimate samples
- ``stage2.<modality>.views``, ``stage2.<modality>.splits``: a Stage 2's view order and split
  positions (the modality it fits: ``thermal``, or ``rgb`` for RGB-only, a two-surface run's
  RGB Stage 2 and the deformable-3dgs baseline)
- ``stage3.views.rgb``, ``stage3.views.thermal``, ``stage3.splits.smoke``,
  ``stage3.splits.surface``: Stage 3's view orders and split positions
- ``stage2.deform``, ``stage3.deform``: the deformation model's initial weights
- ``torch.global``: torch's global generator, for any library draw not named above
"""
from __future__ import annotations

import numpy as np


def seed_sequence(seed: int, name: str) -> np.random.SeedSequence:
    """The stream ``name`` of run seed ``seed`` (a non-negative integer)."""
    return np.random.SeedSequence(entropy=seed, spawn_key=tuple(name.encode()))


def numpy_stream(seed: int, name: str) -> np.random.Generator:
    """A numpy generator on stream ``name``."""
    return np.random.default_rng(seed_sequence(seed, name))


def stream_seed(seed: int, name: str) -> int:
    """A 64-bit seed for a torch generator on stream ``name``."""
    return int(seed_sequence(seed, name).generate_state(1, dtype=np.uint64)[0])
