"""The camera rig: unsynchronised clocks on the sim grid, rigid poses, pinhole intrinsics."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from generator.presets import load_preset
from generator.rig import intrinsics, look_at, rgb_frames, thermal_frames, timeline


def test_clocks_are_unsynchronised_with_exact_timestamps() -> None:
    spec = load_preset("demo")
    line = timeline(spec)
    rgb, th = rgb_frames(spec, line), thermal_frames(spec, line)
    assert len(rgb) == spec.frames and len(th) >= 2
    for f in rgb:
        assert f.timestamp_s == f.index / spec.rig.rgb.fps
    for f in th:
        assert f.timestamp_s == spec.rig.thermal.time_offset_s + f.index / spec.rig.thermal.fps
    for f in rgb + th:
        assert 0.0 <= f.time <= 1.0
        # The smoke state is the bake at this very instant: a fractional frame when between steps.
        assert f.sim_frame == pytest.approx(1 + line.warmup_frames + f.timestamp_s * spec.sim.fps, abs=1e-6)
    assert rgb[0].time == 0.0 and rgb[-1].time == 1.0
    assert {f.sim_frame for f in th}.isdisjoint({f.sim_frame for f in rgb})
    assert any(f.split == "test" for f in rgb) and all(f.split == "train" for f in th)


def test_static_smoke_freezes_every_frame_at_the_first_state() -> None:
    spec = load_preset("demo")
    spec = replace(spec, sim=replace(spec.sim, static=True))
    line = timeline(spec)
    frames = rgb_frames(spec, line) + thermal_frames(spec, line)
    assert {f.sim_frame for f in frames} == {1 + line.warmup_frames}
    assert all(f.next_weight == 0.0 for f in frames)


def test_poses_are_rigid_and_look_at_the_target() -> None:
    target = np.array([0.3, -0.2, 0.5])
    c2w = look_at(np.array([4.0, 1.0, 2.0]), target)
    r = c2w[:3, :3]
    assert np.allclose(r.T @ r, np.eye(3)) and math.isclose(np.linalg.det(r), 1.0)
    forward = -r[:, 2]
    to_target = (target - c2w[:3, 3]) / np.linalg.norm(target - c2w[:3, 3])
    assert np.allclose(forward, to_target)
    assert r[2, 1] > 0  # camera up has a positive world-Z component


def test_thermal_camera_keeps_its_baseline() -> None:
    spec = load_preset("demo")
    spec = replace(spec, rig=replace(spec.rig, thermal=replace(spec.rig.thermal, fps=spec.rig.rgb.fps,
                                                                time_offset_s=0.0)))
    line = timeline(spec)
    for a, b in zip(rgb_frames(spec, line), thermal_frames(spec, line)):
        assert a.timestamp_s == b.timestamp_s
        offset_cam = a.c2w[:3, :3].T @ (b.c2w[:3, 3] - a.c2w[:3, 3])
        assert np.allclose(offset_cam, spec.rig.thermal.baseline_m)


def test_intrinsics_match_the_field_of_view() -> None:
    k = intrinsics(load_preset("demo").rig.rgb)
    assert math.isclose(math.degrees(k.camera_angle_x), 55.0)
    assert (k.cx, k.cy) == (k.width / 2, k.height / 2)
