"""The axes of the scene sampler, their distributions, and pins (`--set AXIS=VALUE`).

Each axis takes one uniform number from its own random stream, keyed by the seed and the
axis's name, and maps it through its distribution. A pin either fixes the value or narrows the
range (`LO:HI`) the same uniform number is mapped into, so pinning one axis never changes
another axis's draw.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from contracts.set_items import read_set_value, split_set_item
from generator.errors import SpecError

PIN_FLAG = "--set"


def stream(seed: int, name: str) -> np.random.Generator:
    """The random stream of one named part of a drawn scene (no global state)."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


@dataclass(frozen=True)
class Axis:
    """`kind` is int, uniform, log_uniform, choice or bool. Numbers draw from `default`
    (lo, hi) and a pin may take any value within `limits`; a choice draws from `choices` with
    `weights`; a bool is true with probability `default[0]`."""

    name: str
    kind: str
    default: tuple[float, ...] = ()
    limits: tuple[float, float] = (0.0, 0.0)
    choices: tuple[str, ...] = ()
    weights: tuple[float, ...] = ()
    doc: str = ""

    @property
    def numeric(self) -> bool:
        return self.kind in ("int", "uniform", "log_uniform")

    def at(self, u: float, interval: tuple[float, float] | None = None) -> Any:
        """The value the uniform number `u` in [0, 1) maps to (within `interval` when pinned)."""
        if self.kind == "bool":
            return bool(u < self.default[0])
        if self.kind == "choice":
            edges = np.cumsum(self.weights) / sum(self.weights)
            return self.choices[int(np.searchsorted(edges, u, side="right"))]
        lo, hi = interval or (self.default[0], self.default[1])
        if self.kind == "int":
            return int(min(hi, lo + math.floor(u * (hi - lo + 1))))
        if self.kind == "log_uniform":
            return float(math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))))
        return float(lo + u * (hi - lo))

    def describe_values(self) -> str:
        if self.kind == "bool":
            return "true or false"
        if self.kind == "choice":
            return f"one of {', '.join(self.choices)}"
        what = "an integer" if self.kind == "int" else "a number"
        return f"{what} from {self.limits[0]:g} to {self.limits[1]:g}, or a range LO:HI"


AXES: tuple[Axis, ...] = (
    Axis("objects.count", "int", (3, 8), (1, 8), doc="objects on the ground, besides the ground itself"),
    Axis("sources.count", "int", (1, 3), (1, 3), doc="smoke sources"),
    Axis("fire", "bool", (0.3,), doc="whether the first source burns (fire and smoke)"),
    Axis("smoke.particles", "choice", choices=("organic_smoke", "soot"), weights=(1.0, 1.0),
         doc="the Mie particle population"),
    Axis("smoke.optical_depth", "log_uniform", (0.1, 3.5), (0.01, 20.0),
         doc="mean RGB optical depth of the smoke over the RGB views"),
    Axis("sim.wind", "uniform", (0.0, 3.0), (0.0, 10.0), doc="wind strength, horizontal, random direction"),
    Axis("rig.trajectory", "choice", choices=("orbit", "flyover"), weights=(0.7, 0.3), doc="the drone's path"),
    Axis("thermal.scale", "uniform", (0.3, 0.5), (0.1, 1.0), doc="thermal resolution over RGB resolution"),
    Axis("thermal.time_offset_s", "uniform", (0.0, 0.1), (0.0, 1.0), doc="thermal clock offset"),
    Axis("thermal.baseline_m", "uniform", (0.03, 0.15), (0.0, 1.0),
         doc="distance of the thermal camera from the RGB camera"),
    Axis("lights.ambient_temperature_k", "uniform", (278.0, 308.0), (230.0, 330.0), doc="air temperature"),
    Axis("lights.sun_elevation_deg", "uniform", (15.0, 75.0), (-10.0, 90.0), doc="sun elevation"),
)
AXIS_BY_NAME = {a.name: a for a in AXES}
#: Short names: the last part of an axis name, where no other axis shares it.
ALIASES = {short: a.name for a in AXES for short in [a.name.rpartition(".")[2]]
           if sum(b.name.rpartition(".")[2] == short for b in AXES) == 1 and short != a.name}


@dataclass(frozen=True)
class Pin:
    """A fixed `value`, or a `range` (lo, hi) a numeric axis draws within."""

    axis: str
    value: Any = None
    range: tuple[float, float] | None = None


def _number(axis: Axis, key: str, raw: str) -> float:
    value = read_set_value(key, raw, PIN_FLAG)
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and axis.kind == "int" and not float(value).is_integer():
        ok = False
    if not ok or not axis.limits[0] <= value <= axis.limits[1]:
        raise SpecError(PIN_FLAG, key, f"must be {axis.describe_values()}, got {raw!r}")
    if axis.kind == "log_uniform" and value <= 0:
        raise SpecError(PIN_FLAG, key, f"must be greater than 0, got {raw!r}")
    return int(value) if axis.kind == "int" else float(value)


def parse_pin(item: str) -> Pin:
    """One `AXIS=VALUE` or `AXIS=LO:HI` item; an unknown axis or a bad value is one SpecError."""
    try:
        key, raw = split_set_item(item, PIN_FLAG)
    except ValueError as exc:
        raise SpecError(PIN_FLAG, "", str(exc).partition(": ")[2]) from None
    name = ALIASES.get(key, key)
    if name not in AXIS_BY_NAME:
        raise SpecError(PIN_FLAG, key, f"unknown axis; the axes are {', '.join(AXIS_BY_NAME)}")
    axis = AXIS_BY_NAME[name]
    raw = raw.strip()
    if axis.numeric:
        if ":" in raw:  # a range; each end read as YAML, never the whole (YAML 1.1 reads 1:2 as 62)
            lo_raw, _, hi_raw = raw.partition(":")
            lo, hi = _number(axis, key, lo_raw), _number(axis, key, hi_raw)
            if lo > hi:
                raise SpecError(PIN_FLAG, key, f"range {raw!r} runs backwards; write LO:HI")
            return Pin(name, range=(lo, hi))
        return Pin(name, value=_number(axis, key, raw))
    value = read_set_value(key, raw, PIN_FLAG)
    if axis.kind == "bool" and not isinstance(value, bool):
        raise SpecError(PIN_FLAG, key, f"must be {axis.describe_values()}, got {raw!r}")
    if axis.kind == "choice" and value not in axis.choices:
        raise SpecError(PIN_FLAG, key, f"must be {axis.describe_values()}, got {raw!r}")
    return Pin(name, value=value)


def parse_pins(items: list[str]) -> dict[str, Pin]:
    pins: dict[str, Pin] = {}
    for item in items:
        pin = parse_pin(item)
        if pin.axis in pins:
            raise SpecError(PIN_FLAG, pin.axis, "pinned twice")
        pins[pin.axis] = pin
    return pins


def draw_axes(seed: int, pins: dict[str, Pin] | None = None) -> dict[str, Any]:
    """Every axis's value for `seed`, pins applied."""
    pins = pins or {}
    values: dict[str, Any] = {}
    for axis in AXES:
        u = float(stream(seed, f"axis:{axis.name}").random())
        pin = pins.get(axis.name)
        if pin is not None and pin.range is None:
            values[axis.name] = pin.value
        else:
            values[axis.name] = axis.at(u, pin.range if pin is not None else None)
    return values
