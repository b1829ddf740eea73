"""The scene sampler's materials: surface finishes (colour, texture, emissivity) and the
temperatures of the three thermal roles an object can have.

Emissivities are LWIR (8-14 um) values of the kind tabulated for these surfaces: paints,
plastics, wood, fabric, stone and soil 0.85-0.98, bare metal 0.2-0.5. Temperatures: a clothed
person's surface 305-310 K, engines and heaters 320-380 K, everything else near the ambient
temperature, offset by what the asset's manifest entry says (a sun-heated roof is warmer, a
transpiring plant cooler).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from generator.spec import MaterialSpec

Colour = tuple[float, float, float]


@dataclass(frozen=True)
class Finish:
    roughness: tuple[float, float]
    metallic: float
    textures: tuple[str, ...]
    texture_scale: tuple[float, float]
    emissivity: tuple[float, float]
    colours: tuple[Colour, ...]


_PAINT = ((0.7, 0.1, 0.08), (0.9, 0.7, 0.1), (0.12, 0.25, 0.55), (0.15, 0.4, 0.18), (0.85, 0.85, 0.82),
          (0.35, 0.36, 0.38), (0.9, 0.45, 0.08))
FINISHES: dict[str, Finish] = {
    "painted_metal": Finish((0.3, 0.6), 0.3, ("none", "noise"), (10.0, 40.0), (0.85, 0.93), _PAINT),
    "bare_metal": Finish((0.2, 0.5), 0.9, ("none", "noise"), (15.0, 40.0), (0.2, 0.5),
                         ((0.55, 0.56, 0.58), (0.4, 0.4, 0.42), (0.62, 0.6, 0.55))),
    "plastic": Finish((0.3, 0.6), 0.0, ("none", "noise"), (20.0, 60.0), (0.9, 0.95), _PAINT),
    "wood": Finish((0.5, 0.8), 0.0, ("wave",), (4.0, 12.0), (0.88, 0.94),
                   ((0.45, 0.28, 0.14), (0.6, 0.45, 0.3), (0.3, 0.18, 0.1))),
    "fabric": Finish((0.85, 1.0), 0.0, ("noise", "checker", "magic"), (8.0, 40.0), (0.93, 0.97),
                     ((0.2, 0.25, 0.35), (0.5, 0.1, 0.12), (0.3, 0.35, 0.2), (0.6, 0.55, 0.45))),
    "stone": Finish((0.8, 0.95), 0.0, ("voronoi", "noise"), (3.0, 10.0), (0.9, 0.95),
                    ((0.45, 0.43, 0.4), (0.6, 0.55, 0.45), (0.3, 0.3, 0.32))),
}
GROUNDS: dict[str, Finish] = {
    "asphalt": Finish((0.85, 0.95), 0.0, ("voronoi", "noise"), (10.0, 30.0), (0.93, 0.97),
                      ((0.16, 0.16, 0.17), (0.22, 0.21, 0.2))),
    "concrete": Finish((0.85, 0.95), 0.0, ("noise", "checker"), (2.0, 12.0), (0.92, 0.95),
                       ((0.55, 0.54, 0.5), (0.62, 0.6, 0.56))),
    "grass": Finish((0.8, 0.95), 0.0, ("noise", "voronoi"), (2.0, 8.0), (0.96, 0.98),
                    ((0.2, 0.35, 0.1), (0.3, 0.4, 0.15))),
    "dirt": Finish((0.9, 1.0), 0.0, ("noise",), (1.5, 6.0), (0.92, 0.96),
                   ((0.35, 0.26, 0.17), (0.45, 0.35, 0.22))),
    "tiles": Finish((0.7, 0.85), 0.0, ("checker",), (1.5, 4.0), (0.9, 0.94),
                    ((0.66, 0.36, 0.22), (0.5, 0.5, 0.5))),
}

PERSON_K = (305.0, 310.0)
HOT_K = (320.0, 380.0)
AMBIENT_OFFSET_LIMIT_K = 8.0
"""A near-ambient object sits at ambient plus its manifest temperature's offset from 293.15 K,
clipped to this, plus a jitter of up to 1.5 K."""
MANIFEST_AMBIENT_K = 293.15


def rounded(x: float, digits: int = 3) -> float:
    """A drawn number as the spec writes it (+ 0.0: no -0.0 in the YAML)."""
    return round(float(x), digits) + 0.0


def _colour(rng: np.random.Generator, colours: tuple[Colour, ...]) -> list[float]:
    base = np.asarray(colours[int(rng.integers(len(colours)))])
    return [rounded(v) for v in np.clip(base + rng.uniform(-0.05, 0.05, 3), 0.02, 0.95)]


def draw_look(rng: np.random.Generator, finish: Finish) -> dict[str, Any]:
    """Colour, roughness, metallic and texture of one surface, and its emissivity."""
    base = _colour(rng, finish.colours)
    kind = finish.textures[int(rng.integers(len(finish.textures)))]
    look: dict[str, Any] = {"base_color": base, "roughness": rounded(rng.uniform(*finish.roughness)),
                            "metallic": finish.metallic, "emissivity": rounded(rng.uniform(*finish.emissivity))}
    if kind != "none":
        look["texture"] = {"kind": kind, "scale": rounded(rng.uniform(*finish.texture_scale), 2),
                           "color2": [rounded(v * rng.uniform(0.55, 0.85)) for v in base],
                           "detail": rounded(rng.uniform(1.0, 8.0), 1)}
    return look


def manifest_look(material: MaterialSpec) -> dict[str, Any]:
    """An asset's own appearance and emissivity from its manifest entry."""
    look: dict[str, Any] = {"base_color": list(material.base_color), "roughness": material.roughness,
                            "metallic": material.metallic, "emissivity": material.emissivity}
    if material.texture.kind != "none":
        t = material.texture
        look["texture"] = {"kind": t.kind, "scale": t.scale, "color2": list(t.color2), "detail": t.detail,
                           "mortar_color": list(t.mortar_color)}
    return look


def temperature(rng: np.random.Generator, role: str, ambient_k: float, manifest_k: float) -> tuple[float, float]:
    """(temperature, texture-driven variation) of an object of thermal `role`."""
    if role == "person":
        return rounded(rng.uniform(*PERSON_K), 2), 2.0
    if role == "hot":
        return rounded(rng.uniform(*HOT_K), 2), rounded(rng.uniform(5.0, 25.0), 1)
    offset = float(np.clip(manifest_k - MANIFEST_AMBIENT_K, -AMBIENT_OFFSET_LIMIT_K, AMBIENT_OFFSET_LIMIT_K))
    return rounded(ambient_k + offset + rng.uniform(-1.5, 1.5), 2), rounded(rng.uniform(0.0, 3.0), 1)
