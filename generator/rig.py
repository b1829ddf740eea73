"""The drone camera rig: unsynchronised RGB and thermal cameras on one moving body.

Poses are camera-to-world in the Blender/OpenGL camera convention (+X right, +Y up,
looking along -Z), the same convention `transforms_*.json` stores. Each camera keeps
its own clock: a frame's timestamp is exact (never snapped to the simulation grid), and
the smoke state rendered for it is the bake interpolated linearly between the two
simulation frames around that instant (`FrameSample.sim_frame` is fractional).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from generator.spec import CameraSpec, SceneSpec, TrajectorySpec


@dataclass(frozen=True)
class Intrinsics:
    width: int
    height: int
    fl_x: float
    fl_y: float
    cx: float
    cy: float

    @property
    def camera_angle_x(self) -> float:
        return 2.0 * math.atan(self.width / (2.0 * self.fl_x))

    def matrix(self) -> np.ndarray:
        return np.array([[self.fl_x, 0.0, self.cx], [0.0, self.fl_y, self.cy], [0.0, 0.0, 1.0]])


SIM_WEIGHT_DIGITS = 6  # interpolation weights are rounded so that plans are exactly reproducible


@dataclass(frozen=True)
class FrameSample:
    index: int
    timestamp_s: float
    time: float
    sim_frame: float  # Blender frame position of the smoke state; fractional between baked frames
    c2w: np.ndarray
    split: str

    @property
    def stem(self) -> str:
        return f"{self.index:04d}"

    @property
    def base_frame(self) -> int:
        """The baked frame at or before the instant."""
        return int(np.floor(self.sim_frame))

    @property
    def next_weight(self) -> float:
        """Weight of the following baked frame in the linear interpolation (0 = on a baked frame)."""
        return round(self.sim_frame - self.base_frame, SIM_WEIGHT_DIGITS)


@dataclass(frozen=True)
class Timeline:
    """Maps capture times onto Blender frames: frame 1 is the first simulated step."""

    sim_fps: int
    warmup_frames: int
    duration_s: float
    static: bool

    def sim_frame(self, timestamp_s: float) -> float:
        """Blender frame position of the smoke state at `timestamp_s` (frozen when static)."""
        step = 0.0 if self.static else round(timestamp_s * self.sim_fps, SIM_WEIGHT_DIGITS)
        return 1 + self.warmup_frames + (step if step != int(step) else int(step))

    def normalised(self, timestamp_s: float) -> float:
        return 0.0 if self.duration_s <= 0 else min(1.0, max(0.0, timestamp_s / self.duration_s))



def intrinsics(camera: CameraSpec, width: int | None = None, height: int | None = None) -> Intrinsics:
    """Pinhole intrinsics with a horizontal field of view and square pixels."""
    w = width or camera.width
    h = height or camera.height
    fl = w / (2.0 * math.tan(math.radians(camera.fov_deg) / 2.0))
    return Intrinsics(w, h, fl, fl, w / 2.0, h / 2.0)


WORLD_UP = np.array([0.0, 0.0, 1.0])


def look_at(position: np.ndarray, target: np.ndarray, up: np.ndarray = WORLD_UP) -> np.ndarray:
    """c2w with the camera at `position` looking at `target`, world +Z kept up."""
    forward = target - position
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        raise ValueError("camera position coincides with its look-at target")
    forward = forward / norm
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-6:
        right = np.cross(forward, np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, cam_up, -forward, position
    return c2w


def rig_pose(trajectory: TrajectorySpec, u: float) -> np.ndarray:
    """Pose of the rig body (= RGB camera) at normalised path parameter u in [0, 1]."""
    if trajectory.kind == "orbit":
        angle = math.radians(trajectory.start_deg + trajectory.sweep_deg * u)
        center = np.asarray(trajectory.center)
        position = center + np.array([trajectory.radius * math.cos(angle), trajectory.radius * math.sin(angle),
                                      trajectory.height])
        return look_at(position, center)
    start, end = np.asarray(trajectory.start), np.asarray(trajectory.end)
    look_from, look_to = np.asarray(trajectory.look_from), np.asarray(trajectory.look_to)
    return look_at(start + (end - start) * u, look_from + (look_to - look_from) * u)


def thermal_pose(rgb_c2w: np.ndarray, baseline_m: tuple[float, float, float]) -> np.ndarray:
    """The thermal camera sits `baseline_m` away in the RGB camera frame, same orientation."""
    c2w = rgb_c2w.copy()
    c2w[:3, 3] = rgb_c2w[:3, 3] + rgb_c2w[:3, :3] @ np.asarray(baseline_m)
    return c2w


def timeline(spec: SceneSpec) -> Timeline:
    duration = (spec.frames - 1) / spec.rig.rgb.fps if spec.frames > 1 else 0.0
    warmup = int(round(spec.sim.warmup_s * spec.sim.fps))
    return Timeline(spec.sim.fps, warmup, duration, spec.sim.static)


def last_baked_frame(frames: list[FrameSample]) -> int:
    """The last baked frame any of these frames interpolates from."""
    return max(f.base_frame + (f.next_weight > 0) for f in frames)


def rgb_frames(spec: SceneSpec, line: Timeline) -> list[FrameSample]:
    held_out = spec.test_frames()
    out = []
    for i in range(spec.frames):
        ts = i / spec.rig.rgb.fps
        u = line.normalised(ts)
        out.append(FrameSample(i, ts, u, line.sim_frame(ts), rig_pose(spec.rig.trajectory, u),
                               "test" if i in held_out else "train"))
    return out


def thermal_frames(spec: SceneSpec, line: Timeline) -> list[FrameSample]:
    cam = spec.rig.thermal
    out: list[FrameSample] = []
    j = 0
    while True:
        ts = cam.time_offset_s + j / cam.fps
        if j > 0 and ts > line.duration_s + 1e-9:  # the first thermal frame is always taken
            break
        u = line.normalised(ts)
        pose = thermal_pose(rig_pose(spec.rig.trajectory, u), cam.baseline_m)
        out.append(FrameSample(j, ts, u, line.sim_frame(ts), pose, "train"))
        j += 1
    return out
