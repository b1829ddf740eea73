"""The validation split: RGB training frames held out for every choice a run or a study makes.

Why: the test split (every 8th RGB frame, fixed by the dataset) must never decide anything, so
tuning needs frames of its own. Every ``every``-th RGB frame that the dataset marks ``train``
(counting from frame 0, so with the dataset's test frames at ``i % 8 == 4`` the two never meet)
is relabelled ``val``: it is neither trained on nor part of the test score. Thermal frames stay
in training; they are not scored.
"""
from __future__ import annotations

from scenes.scene import Frame

MIN_TRAIN_FRAMES = 2


def hold_out_validation(frames: list[Frame], every: int) -> list[int]:
    """Relabel RGB train frames ``i % every == 0`` as ``val``; returns their indices.

    ``every`` 0 holds out nothing. Raises ValueError (naming ``validation_every``) when fewer than
    ``MIN_TRAIN_FRAMES`` training frames would remain.
    """
    if every < 0 or every == 1:
        raise ValueError(f"validation_every: must be 0 (none) or at least 2, got {every}")
    if every == 0:
        return []
    chosen = [i for i, f in enumerate(frames) if f.split == "train" and i % every == 0]
    remaining = sum(f.split == "train" for f in frames) - len(chosen)
    if remaining < MIN_TRAIN_FRAMES:
        raise ValueError(f"validation_every: {every} would leave {remaining} RGB training frame(s) of "
                         f"{len(frames)}; use 0 for this dataset or a larger value")
    for i in chosen:
        frames[i].split = "val"
    return chosen
