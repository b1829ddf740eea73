"""The ten-scene synthetic benchmark: its scenes and the size profiles it is generated at.

A profile is one set of command-line overrides applied to every scene, so that the same
presets serve a 2-core smoke test (`bench`) and a paper-scale dataset (`paper`). The
presets themselves (`generator/presets/NAME.yaml`) hold the scene at its designed size:
150 frames, RGB 400x300, thermal 160x120, 64 samples, a 64-96 voxel simulation.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from generator.errors import SpecError
from generator.spec import Overrides, SceneSpec

# Each scene and the paper scene it stands in for (its density is that scene's).
BENCHMARK_SCENES: dict[str, str] = {
    "chair": "chair",
    "plant": "ficus",
    "brick_toy": "lego",
    "food_plate": "hotdog",
    "machine": "musclecar",
    "house": "house",
    "forest": "forest",
    "excavator": "caterpillar",
    "rover": "mars",
    "room": "room",
}
OBJECT_LEVEL = ("chair", "plant", "brick_toy", "food_plate", "machine")

# What `density` means here: the presets' `extinction_per_m` is calibrated (from a `bench`
# run, see `generator.benchmark_cli.extinction_scale`) so that the mean RGB smoke opacity
# over the pixels that have smoke (opacity above the mask threshold) is this times the
# density: 0.16 for the paper's lightest scene (0.2), 0.8 for its densest (1.0).
OPACITY_PER_DENSITY = 0.8

# What counts as smoke that moves strongly: a wind force field or vorticity confinement at
# least this strong, or an inflow at least this fast (m/s).
STRONG_WIND = 2.0
STRONG_VORTICITY = 2.0
STRONG_INFLOW_M_S = 1.5


@dataclass(frozen=True)
class Profile:
    name: str
    description: str
    overrides: Overrides

    def kwargs(self) -> dict[str, Any]:
        """The overrides as keyword arguments for `generator.api.generate` (unset ones left out)."""
        return {k: v for k, v in asdict(self.overrides).items() if v is not None}


PROFILES: dict[str, Profile] = {
    "bench": Profile(
        "bench", "sized for a 2-core machine: the first second of each scene at thumbnail size",
        Overrides(frames=12, resolution=(96, 72), thermal_resolution=(48, 36), samples=16, sim_resolution=32)),
    "standard": Profile(
        "standard", "5 s of smoke (60 RGB frames at 12 fps) at 200x150 RGB / 80x60 thermal, 32 denoised "
        "samples, 48-voxel simulation: the size at which smoke uncovers the surface over time",
        Overrides(frames=60, resolution=(200, 150), thermal_resolution=(80, 60), samples=32, sim_resolution=48)),
    "paper": Profile(
        "paper", "150 frames at 800x600 RGB / 320x240 thermal, 128 samples, 128-voxel simulation",
        Overrides(frames=150, resolution=(800, 600), thermal_resolution=(320, 240), samples=128,
                  sim_resolution=128)),
}


RANDOM_PROFILE = Profile(
    "random", "the size of the random sets (generator.sampler): 2 s of smoke (24 RGB frames at 12 fps) at 160x120 "
    "RGB, thermal at 0.3-0.5x that, 16 denoised samples, 32-voxel simulation",
    Overrides(frames=24, resolution=(160, 120), samples=16, sim_resolution=32))
"""Not one of PROFILES: the sampler draws its scenes at this size (the thermal size is an axis)."""


def get_profile(name: str) -> Profile:
    if name not in PROFILES:
        raise SpecError("--profile", name, f"unknown profile; available: {', '.join(PROFILES)}")
    return PROFILES[name]


def strong_motion(spec: SceneSpec) -> bool:
    """True when the scene's smoke is driven hard: wind, vorticity or a fast inflow."""
    fastest = max((float(np.linalg.norm(s.velocity)) for s in spec.sources), default=0.0)
    return (float(np.linalg.norm(spec.sim.wind)) >= STRONG_WIND or spec.sim.vorticity >= STRONG_VORTICITY
            or fastest >= STRONG_INFLOW_M_S)
