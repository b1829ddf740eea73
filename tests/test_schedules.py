"""Schedules are fractions of their stage: at each profile's own iteration counts they resolve to
the iterations the profiles were written with (so default runs train as before), and at twice
the iterations every window and warm-up doubles while the densification interval stays. A
window that is off (``every`` 0) is compared as off: its start and stop decide nothing."""
from __future__ import annotations

import pytest

from smokeseer.config import PROFILES, DensifyWindow, TrainConfig, at_iteration, make_config

# The iterations each profile used before its schedules became fractions, written out by hand:
# (stage2.densify, stage3.smoke_densify, stage3.surface_densify, stage 2 warm-up, stage 3 warm-up).
BEFORE = {
    "quick": (DensifyWindow(150, 800, 100, 0), DensifyWindow(200, 600, 100, 0), None, 200, 200),
    "standard": (DensifyWindow(300, 2400, 100, 0), DensifyWindow(300, 2400, 100, 0),
                 DensifyWindow(300, 2400, 100, 0), 500, 500),
    "paper": (DensifyWindow(500, 15000, 100, 3000), DensifyWindow(500, 15000, 100, 0), None, 3000, 3000),
}


def _on(window: DensifyWindow) -> DensifyWindow | None:
    return window if window.every > 0 else None


def resolved(cfg: TrainConfig, stage2: int, stage3: int) -> tuple:
    return (_on(cfg.stage2.densify.window(stage2)), _on(cfg.stage3.smoke_densify.window(stage3)),
            _on(cfg.stage3.surface_densify.window(stage3)),
            at_iteration(cfg.stage2.deform_warmup, stage2), at_iteration(cfg.stage3.deform_warmup, stage3))


@pytest.mark.parametrize("profile", PROFILES)
def test_default_iterations_resolve_to_the_profiles_own_schedule(profile: str) -> None:
    cfg = make_config("full", profile)
    assert resolved(cfg, cfg.stage2.iterations, cfg.stage3.iterations) == BEFORE[profile]


@pytest.mark.parametrize("profile", PROFILES)
def test_twice_the_iterations_doubles_every_window(profile: str) -> None:
    base = make_config("full", profile)
    n2, n3 = base.stage2.iterations, base.stage3.iterations
    longer = make_config("full", profile, overrides={"stage2.iterations": 2 * n2, "stage3.iterations": 2 * n3})
    s2, s3, surface, w2, w3 = resolved(longer, 2 * n2, 2 * n3)
    for got, was in zip((s2, s3, surface), BEFORE[profile]):
        assert got == (None if was is None
                       else DensifyWindow(2 * was.start, 2 * was.stop, was.every, 2 * was.opacity_reset_every))
    assert (w2, w3) == (2 * BEFORE[profile][3], 2 * BEFORE[profile][4])


def test_the_stage_builds_its_schedule_from_its_own_iterations() -> None:
    """``--set stage3.iterations=6000`` on the standard profile: densification now stops at 4800
    (it stayed at 2400 when windows were iterations), and the warm-up ends at 1000."""
    cfg = make_config("full", "standard", overrides={"stage3.iterations": 6000})
    assert cfg.stage3.smoke_densify.window(cfg.stage3.iterations).stop == 4800
    assert at_iteration(cfg.stage3.deform_warmup, cfg.stage3.iterations) == 1000


def test_fractions_resolve_to_the_nearest_iteration() -> None:
    assert [at_iteration(f, 10) for f in (0.0, 0.04, 0.05, 0.26, 1.0)] == [0, 0, 1, 3, 10]
