"""Procedural asset recipes: Blender primitives and modifiers, one function per recipe.

A recipe takes the object name and its manifest/spec `params` and returns a new mesh
object at the origin with unit transform, resting on z = 0 unless its docstring says
otherwise; placement happens in the scene builder. Composite recipes build their parts
from bmesh primitives, give them modifiers (array, bevel, solidify, screw, displace,
boolean, subdivision), then bake everything into one mesh (`Parts.join`), so the
object carries no live modifiers and one material. Randomness comes from a `seed`
param through numpy's PCG64, so a recipe builds the same mesh every time.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from itertools import pairwise
from typing import Any

import bpy

# isort: split
import bmesh  # importable only once bpy is loaded
import numpy as np
from mathutils import Euler, Matrix, Vector

Recipe = Callable[[str, dict[str, Any]], bpy.types.Object]
RECIPES: dict[str, Recipe] = {}


def recipe(name: str) -> Callable[[Recipe], Recipe]:
    def register(fn: Recipe) -> Recipe:
        RECIPES[name] = fn
        return fn

    return register


def _named(obj: bpy.types.Object, name: str) -> bpy.types.Object:
    obj.name = name
    obj.data.name = name
    return obj


def _bevel(obj: bpy.types.Object, width: float, segments: int = 2) -> None:
    if width > 0:
        mod = obj.modifiers.new("Bevel", "BEVEL")
        mod.width = width
        mod.segments = segments


@recipe("ground_plane")
def ground_plane(name: str, p: dict[str, Any]) -> bpy.types.Object:
    bpy.ops.mesh.primitive_plane_add(size=float(p.get("size", 10.0)))
    return _named(bpy.context.object, name)


@recipe("box")
def box(name: str, p: dict[str, Any]) -> bpy.types.Object:
    sx, sy, sz = (float(v) for v in p.get("dimensions", (1.0, 1.0, 1.0)))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, sz / 2.0))
    obj = _named(bpy.context.object, name)
    obj.scale = (sx, sy, sz)
    bpy.ops.object.transform_apply(location=True, scale=True)
    _bevel(obj, float(p.get("bevel", 0.02)))
    return obj


@recipe("sphere")
def sphere(name: str, p: dict[str, Any]) -> bpy.types.Object:
    radius = float(p.get("radius", 0.5))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, segments=int(p.get("segments", 32)),
                                         ring_count=int(p.get("rings", 16)), location=(0.0, 0.0, radius))
    obj = _named(bpy.context.object, name)
    bpy.ops.object.transform_apply(location=True)
    bpy.ops.object.shade_smooth()
    return obj


@recipe("cylinder")
def cylinder(name: str, p: dict[str, Any]) -> bpy.types.Object:
    radius, depth = float(p.get("radius", 0.4)), float(p.get("depth", 1.0))
    bpy.ops.mesh.primitive_cylinder_add(radius=radius, depth=depth, vertices=int(p.get("vertices", 32)),
                                        location=(0.0, 0.0, depth / 2.0))
    obj = _named(bpy.context.object, name)
    bpy.ops.object.transform_apply(location=True)
    _bevel(obj, float(p.get("bevel", 0.01)))
    return obj


def mesh_from_arrays(name: str, vertices: np.ndarray, faces: np.ndarray) -> bpy.types.Object:
    """A mesh object from trimesh-checked arrays (metres), without Blender's importers.

    Shading is smooth except across edges sharper than `SHARP_ANGLE_DEG`, so scanned or
    generated organic meshes (terrain, rocks) are not faceted while hard edges stay hard.
    """
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", np.asarray(vertices, dtype=np.float32).ravel())
    faces = np.asarray(faces, dtype=np.int32)
    mesh.loops.add(faces.size)
    mesh.loops.foreach_set("vertex_index", faces.ravel())
    mesh.polygons.add(len(faces))
    mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    mesh.polygons.foreach_set("loop_total", np.full(len(faces), 3, dtype=np.int32))
    mesh.update(calc_edges=True)
    mesh.validate()
    bm = bmesh.new()
    bm.from_mesh(mesh)
    _smooth_by_angle(bm)
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


# --- building blocks for composite recipes -------------------------------------------------

SHARP_ANGLE_DEG = 40.0
Vec3 = Sequence[float]


def _smooth_by_angle(bm: bmesh.types.BMesh, sharp_angle_deg: float = SHARP_ANGLE_DEG) -> None:
    limit = math.radians(sharp_angle_deg)
    for face in bm.faces:
        face.smooth = True
    for edge in bm.edges:
        edge.smooth = not (edge.is_manifold and edge.calc_face_angle(0.0) > limit)


def _matrix(location: Vec3 = (0.0, 0.0, 0.0), rotation_deg: Vec3 = (0.0, 0.0, 0.0),
            scale: Vec3 = (1.0, 1.0, 1.0)) -> Matrix:
    return Matrix.LocRotScale(Vector(location), Euler([math.radians(a) for a in rotation_deg]), Vector(scale))


def _link(name: str, bm: bmesh.types.BMesh) -> bpy.types.Object:
    """A new scene object owning the bmesh's geometry (the bmesh is freed)."""
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _mod(obj: bpy.types.Object, kind: str, **settings: Any) -> bpy.types.Modifier:
    mod = obj.modifiers.new(kind.lower(), kind)
    for key, value in settings.items():
        setattr(mod, key, value)
    return mod


def _array(obj: bpy.types.Object, count: int, offset: Vec3) -> bpy.types.Modifier:
    """`count` copies, each shifted by `offset` metres from the previous one."""
    return _mod(obj, "ARRAY", count=max(1, int(count)), use_relative_offset=False, use_constant_offset=True,
                constant_offset_displace=tuple(offset))


def _tube_bmesh(points: np.ndarray, radii: np.ndarray, segments: int, caps: str) -> bmesh.types.BMesh:
    """A tube along a polyline (parallel-transport frames), with round, flat or no caps."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2 or np.any(np.linalg.norm(np.diff(pts, axis=0), axis=1) < 1e-9):
        raise ValueError("a tube needs at least two distinct consecutive points")
    radii = np.broadcast_to(np.asarray(radii, dtype=float), (len(pts),))
    tangents = np.gradient(pts, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    seed_axis = np.array([0.0, 0.0, 1.0]) if abs(tangents[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    normal = np.cross(tangents[0], seed_axis)
    normal /= np.linalg.norm(normal)
    angles = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    bm = bmesh.new()
    rings: list[list[bmesh.types.BMVert]] = []

    def ring(center: np.ndarray, t: np.ndarray, n: np.ndarray, r: float) -> list[bmesh.types.BMVert]:
        b = np.cross(t, n)
        return [bm.verts.new(center + r * (math.cos(a) * n + math.sin(a) * b)) for a in angles]

    normals = []
    for i, t in enumerate(tangents):
        normal = normal - np.dot(normal, t) * t
        normal /= np.linalg.norm(normal)
        normals.append(normal)
        rings.append(ring(pts[i], t, normal, radii[i]))
    if caps == "round":
        steps = max(2, segments // 4)
        for end, sign in ((0, -1.0), (len(pts) - 1, 1.0)):
            chain = [rings[end]]
            for j in range(1, steps):
                phi = 0.5 * math.pi * j / steps
                center = pts[end] + sign * tangents[end] * radii[end] * math.sin(phi)
                chain.append(ring(center, tangents[end], normals[end], radii[end] * math.cos(phi)))
            pole = bm.verts.new(pts[end] + sign * tangents[end] * radii[end])
            for a, b in pairwise(chain):
                for k in range(segments):
                    bm.faces.new((a[k], a[(k + 1) % segments], b[(k + 1) % segments], b[k]))
            for k in range(segments):
                bm.faces.new((chain[-1][k], chain[-1][(k + 1) % segments], pole))
    elif caps == "flat":
        bm.faces.new(rings[0])
        bm.faces.new(rings[-1])
    for a, b in pairwise(rings):
        for k in range(segments):
            bm.faces.new((a[k], a[(k + 1) % segments], b[(k + 1) % segments], b[k]))
    bmesh.ops.recalc_face_normals(bm, faces=bm.faces[:])
    return bm


class Parts:
    """The temporary pieces of one composite recipe. Helpers (boolean cutters, array and
    displacement pivots, textures) are deleted by `join`, which bakes every modifier."""

    def __init__(self) -> None:
        self.parts: list[bpy.types.Object] = []
        self.scratch: list[bpy.types.Object] = []
        self.textures: list[bpy.types.Texture] = []

    def add(self, bm: bmesh.types.BMesh) -> bpy.types.Object:
        obj = _link("part", bm)
        self.parts.append(obj)
        return obj

    def cube(self, size: Vec3, location: Vec3 = (0.0, 0.0, 0.0), rotation_deg: Vec3 = (0.0, 0.0, 0.0),
             bevel: float = 0.0) -> bpy.types.Object:
        bm = bmesh.new()
        bmesh.ops.create_cube(bm, size=1.0, matrix=_matrix(location, rotation_deg, size))
        obj = self.add(bm)
        _bevel(obj, bevel)
        return obj

    def cone(self, r_bottom: float, r_top: float, depth: float, location: Vec3 = (0.0, 0.0, 0.0),
             rotation_deg: Vec3 = (0.0, 0.0, 0.0), segments: int = 24) -> bpy.types.Object:
        """A capped frustum centred on `location`, axis along its local Z."""
        bm = bmesh.new()
        bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=False, segments=segments, radius1=r_bottom,
                              radius2=r_top, depth=depth, matrix=_matrix(location, rotation_deg))
        return self.add(bm)

    def sphere(self, radius: float, location: Vec3 = (0.0, 0.0, 0.0), scale: Vec3 = (1.0, 1.0, 1.0),
               rotation_deg: Vec3 = (0.0, 0.0, 0.0), segments: int = 24, rings: int = 12) -> bpy.types.Object:
        bm = bmesh.new()
        bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius,
                                  matrix=_matrix(location, rotation_deg, scale))
        return self.add(bm)

    def ico(self, radius: float, location: Vec3 = (0.0, 0.0, 0.0), scale: Vec3 = (1.0, 1.0, 1.0),
            subdivisions: int = 2) -> bpy.types.Object:
        bm = bmesh.new()
        bmesh.ops.create_icosphere(bm, subdivisions=subdivisions, radius=radius,
                                   matrix=_matrix(location, (0.0, 0.0, 0.0), scale))
        return self.add(bm)

    def tube(self, points: Sequence[Vec3], radii: float | Sequence[float], segments: int = 12,
             caps: str = "round") -> bpy.types.Object:
        return self.add(_tube_bmesh(np.asarray(points, dtype=float), np.asarray(radii, dtype=float),
                                    segments, caps))

    def lathe(self, profile: Sequence[Sequence[float]], segments: int = 48, thickness: float = 0.0,
              location: Vec3 = (0.0, 0.0, 0.0)) -> bpy.types.Object:
        """A surface of revolution about Z (screw modifier) of an (r, z) profile, optionally solidified."""
        bm = bmesh.new()
        verts = [bm.verts.new((float(r), 0.0, float(z))) for r, z in profile]
        for a, b in pairwise(verts):
            bm.edges.new((a, b))
        obj = self.add(bm)
        obj.location = location
        _mod(obj, "SCREW", angle=2.0 * math.pi, steps=segments, render_steps=segments, axis="Z",
             use_merge_vertices=True, merge_threshold=1e-5, use_normal_calculate=True)
        if thickness > 0:
            _mod(obj, "SOLIDIFY", thickness=thickness, offset=0.0, use_even_offset=True)
        return obj

    def cutter(self, size: Vec3, location: Vec3, rotation_deg: Vec3 = (0.0, 0.0, 0.0)) -> bpy.types.Object:
        """A box used only as a boolean operand; hidden and deleted at join."""
        bm = bmesh.new()
        bmesh.ops.create_cube(bm, size=1.0, matrix=_matrix(location, rotation_deg, size))
        obj = _link("cutter", bm)
        obj.hide_render = True
        self.scratch.append(obj)
        return obj

    def subtract(self, obj: bpy.types.Object, cutter: bpy.types.Object) -> None:
        _mod(obj, "BOOLEAN", operation="DIFFERENCE", object=cutter, solver="EXACT")

    def radial(self, obj: bpy.types.Object, count: int, pivot: Vec3, step_deg: float, axis: str = "Z") -> None:
        """`count` copies of `obj` rotated about the `axis` line through `pivot` (array with an
        offset object): the part's origin moves to the pivot so the copies turn about it."""
        pivot_v = Vector(pivot)
        obj.data.transform(Matrix.Translation(-pivot_v))
        obj.location = pivot_v
        empty = bpy.data.objects.new("pivot", None)
        bpy.context.scene.collection.objects.link(empty)
        empty.location = pivot_v
        empty.rotation_euler = [math.radians(step_deg) if a == axis else 0.0 for a in "XYZ"]
        self.scratch.append(empty)
        _mod(obj, "ARRAY", count=max(1, int(count)), use_relative_offset=False, use_object_offset=True,
             offset_object=empty)

    def displace(self, obj: bpy.types.Object, strength: float, size: float, seed: int = 0,
                 kind: str = "CLOUDS", subdivide: int = 0) -> None:
        """Procedural-texture displacement along normals; the seed moves the texture's origin."""
        if subdivide:
            _mod(obj, "SUBSURF", levels=subdivide, render_levels=subdivide, subdivision_type="SIMPLE")
        tex = bpy.data.textures.new("displace", kind)
        tex.noise_scale = size
        self.textures.append(tex)
        origin = bpy.data.objects.new("texture_origin", None)
        bpy.context.scene.collection.objects.link(origin)
        origin.location = np.random.default_rng(seed).uniform(-50.0, 50.0, 3).tolist()
        self.scratch.append(origin)
        _mod(obj, "DISPLACE", texture=tex, strength=strength, mid_level=0.5, texture_coords="OBJECT",
             texture_coords_object=origin)

    def join(self, name: str, transform: Matrix | None = None) -> bpy.types.Object:
        """Evaluate every part with its modifiers into one mesh; delete parts and helpers."""
        depsgraph = bpy.context.evaluated_depsgraph_get()
        bm = bmesh.new()
        for obj in self.parts:
            evaluated = obj.evaluated_get(depsgraph)
            mesh = evaluated.to_mesh()
            mesh.transform(obj.matrix_world if transform is None else transform @ obj.matrix_world)
            bm.from_mesh(mesh)
            evaluated.to_mesh_clear()
        for obj in self.parts + self.scratch:
            data = obj.data
            bpy.data.objects.remove(obj, do_unlink=True)
            if data is not None and data.users == 0:
                bpy.data.meshes.remove(data)
        for tex in self.textures:
            bpy.data.textures.remove(tex)
        _smooth_by_angle(bm)
        return _link(name, bm)


def _num(p: dict[str, Any], key: str, default: float) -> float:
    return float(p.get(key, default))


def _vec(p: dict[str, Any], key: str, default: Iterable[float]) -> tuple[float, ...]:
    return tuple(float(v) for v in p.get(key, default))


def _rng(p: dict[str, Any]) -> np.random.Generator:
    return np.random.default_rng(int(p.get("seed", 0)))


# --- generic shapes -------------------------------------------------------------------------

@recipe("lathe")
def lathe(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """Surface of revolution of `profile` [[r, z], ...] about Z (plates, pots, bins, dishes);
    `thickness` > 0 solidifies an open profile into a shell."""
    b = Parts()
    b.lathe(p.get("profile", [[0.0, 0.0], [0.5, 0.0], [0.5, 0.5]]), int(p.get("segments", 48)),
            _num(p, "thickness", 0.0))
    return b.join(name)


@recipe("ellipsoid")
def ellipsoid(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """An ellipsoid with semi-axes `radii`, resting on z = 0; `roughness` adds noise bumps."""
    rx, ry, rz = _vec(p, "radii", (0.5, 0.5, 0.5))
    b = Parts()
    part = b.sphere(1.0, (0.0, 0.0, rz), (rx, ry, rz), segments=int(p.get("segments", 32)),
                    rings=int(p.get("rings", 16)))
    if _num(p, "roughness", 0.0) > 0:
        b.displace(part, _num(p, "roughness", 0.0) * min(rx, ry, rz), _num(p, "bump_size", 0.3) * max(rx, ry, rz),
                   int(p.get("seed", 0)), subdivide=1)
    return b.join(name)


@recipe("tube")
def tube(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A tube along `points` (metres, object frame) with `radius` or per-point `radii`;
    caps `round`, `flat` or `none` (sausages, pipes, hoses, logs, sauce lines)."""
    radii = p.get("radii", p.get("radius", 0.05))
    b = Parts()
    b.tube(p.get("points", [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), radii, int(p.get("segments", 16)),
           str(p.get("caps", "round")))
    return b.join(name)


@recipe("wall")
def wall(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A wall built flat in its local XY plane (x along the wall, y up, thickness along z)
    with rectangular `openings` [[x_centre, y_bottom, width, height], ...] cut by booleans
    and an optional gable triangle of height `gable_rise` on top.

    2D textures (brick) read object x and y, so stand the wall up with
    rotation_deg [90, 0, heading]: bricks then run along the wall in horizontal courses.
    The local +z face becomes the outside (heading 0 faces world -y)."""
    length, height, thick = _num(p, "length", 6.0), _num(p, "height", 2.8), _num(p, "thickness", 0.25)
    rise = _num(p, "gable_rise", 0.0)
    bm = bmesh.new()
    outline = [(-length / 2, 0.0), (length / 2, 0.0), (length / 2, height)]
    if rise > 0:
        outline.append((0.0, height + rise))
    outline.append((-length / 2, height))
    face = bm.faces.new([bm.verts.new((x, y, -thick / 2)) for x, y in outline])
    extruded = bmesh.ops.extrude_face_region(bm, geom=[face])
    bmesh.ops.translate(bm, vec=(0.0, 0.0, thick),
                        verts=[v for v in extruded["geom"] if isinstance(v, bmesh.types.BMVert)])
    bmesh.ops.recalc_face_normals(bm, faces=bm.faces[:])
    b = Parts()
    body = b.add(bm)
    for x, y, w, h in p.get("openings", []):
        b.subtract(body, b.cutter((w, h, thick * 3), (x, y + h / 2, 0.0)))
    return b.join(name)


@recipe("gable_roof")
def gable_roof(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """Two roof slopes meeting at a ridge along X, `rise` above the eaves line (z = 0 at the
    wall tops), overhanging by `overhang`, `thickness` thick. 2D textures (brick = tiles)
    lay their rows parallel to the ridge."""
    width, depth = _num(p, "width", 8.0), _num(p, "depth", 6.0)
    rise, over, thick = _num(p, "rise", 2.0), _num(p, "overhang", 0.4), _num(p, "thickness", 0.15)
    half_w, half_d = width / 2 + over, depth / 2 + over
    z_eave = -over * rise / (depth / 2)
    bm = bmesh.new()
    rows = [[bm.verts.new((x, y, z)) for y, z in ((-half_d, z_eave), (0.0, rise), (half_d, z_eave))]
            for x in (-half_w, half_w)]
    for k in range(2):
        face = bm.faces.new((rows[0][k], rows[0][k + 1], rows[1][k + 1], rows[1][k]))
        if face.normal.z < 0:
            face.normal_flip()
    b = Parts()
    roof = b.add(bm)
    _mod(roof, "SOLIDIFY", thickness=thick, offset=-1.0, use_even_offset=True)
    b.cube((2 * half_w, 0.16, 0.16), (0.0, 0.0, rise + 0.03), (45.0, 0.0, 0.0))
    return b.join(name)


# --- furniture and small objects ------------------------------------------------------------

@recipe("chair")
def chair(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A wooden dining chair: tapered square legs, seat, back posts, top rail, `slats`, stretchers.
    Its front faces -y."""
    h, w, d = _num(p, "seat_height", 0.46), _num(p, "width", 0.46), _num(p, "depth", 0.44)
    back, t, leg = _num(p, "back_height", 0.5), _num(p, "thickness", 0.035), _num(p, "leg", 0.036)
    slats = int(p.get("slats", 5))
    b = Parts()
    b.cube((w, d, t), (0.0, 0.0, h - t / 2), bevel=0.006)
    lx, ly = w / 2 - leg / 2 - 0.01, d / 2 - leg / 2 - 0.01
    for sx in (-1, 1):
        for sy in (-1, 1):
            top = h - t if sy < 0 else h + back
            b.cone(leg * 0.75, leg * 0.6, top, (sx * lx, sy * ly, top / 2), (0.0, 0.0, 45.0), segments=4)
        b.tube([(sx * lx, -ly, 0.16), (sx * lx, ly, 0.16)], 0.011, 8, "flat")
    b.tube([(-lx, -ly, 0.22), (lx, -ly, 0.22)], 0.011, 8, "flat")
    b.cube((2 * lx + leg, 0.028, 0.075), (0.0, ly, h + back - 0.04), bevel=0.008)
    spacing = (2 * lx - leg) / (slats + 1)
    slat = b.cube((0.032, 0.016, back - 0.14), (-lx + leg / 2 + spacing, ly, h + (back - 0.14) / 2 + 0.03),
                  bevel=0.004)
    _array(slat, slats, (spacing, 0.0, 0.0))
    return b.join(name)


@recipe("table")
def table(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A table: bevelled top, square legs and an apron."""
    w, d, h = _num(p, "width", 1.2), _num(p, "depth", 0.8), _num(p, "height", 0.75)
    top, leg = _num(p, "top", 0.04), _num(p, "leg", 0.06)
    b = Parts()
    b.cube((w, d, top), (0.0, 0.0, h - top / 2), bevel=0.01)
    lx, ly = w / 2 - leg / 2 - 0.05, d / 2 - leg / 2 - 0.05
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.cube((leg, leg, h - top), (sx * lx, sy * ly, (h - top) / 2), bevel=0.005)
        b.cube((0.025, 2 * ly, 0.1), (sx * lx, 0.0, h - top - 0.05))
    for sy in (-1, 1):
        b.cube((2 * lx, 0.025, 0.1), (0.0, sy * ly, h - top - 0.05))
    return b.join(name)


@recipe("sofa")
def sofa(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """An upholstered sofa: base, arms, back and `cushions` seat cushions; front faces -y."""
    w, d, h = _num(p, "width", 2.0), _num(p, "depth", 0.9), _num(p, "height", 0.8)
    seat, cushions, arm = _num(p, "seat_height", 0.42), int(p.get("cushions", 3)), _num(p, "arm", 0.2)
    b = Parts()
    b.cube((w, d, seat - 0.12), (0.0, 0.0, (seat - 0.12) / 2 + 0.06), bevel=0.03)
    for sx in (-1, 1):
        b.cube((arm, d, h - 0.15), (sx * (w / 2 - arm / 2), 0.0, (h - 0.15) / 2 + 0.06), bevel=0.06)
    b.cube((w - 2 * arm, 0.22, h - 0.06), (0.0, d / 2 - 0.11, (h - 0.06) / 2 + 0.06), bevel=0.06)
    inner = w - 2 * arm
    cushion = b.cube((inner / cushions - 0.01, d - 0.24, 0.14), (-inner / 2 + inner / cushions / 2, -0.1, seat - 0.05),
                     bevel=0.04)
    _array(cushion, cushions, (inner / cushions, 0.0, 0.0))
    for x in (-w / 2 + 0.1, w / 2 - 0.1):
        for y in (-d / 2 + 0.1, d / 2 - 0.1):
            b.cone(0.03, 0.022, 0.06, (x, y, 0.03), segments=8)
    return b.join(name)


@recipe("bookshelf")
def bookshelf(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """An open bookshelf with `shelves` evenly spaced boards and a back panel."""
    w, d, h = _num(p, "width", 1.0), _num(p, "depth", 0.3), _num(p, "height", 1.8)
    shelves, t = int(p.get("shelves", 5)), _num(p, "thickness", 0.022)
    b = Parts()
    for sx in (-1, 1):
        b.cube((t, d, h), (sx * (w / 2 - t / 2), 0.0, h / 2))
    b.cube((w, 0.008, h), (0.0, d / 2 - 0.004, h / 2))
    board = b.cube((w - 2 * t, d, t), (0.0, 0.0, t / 2 + 0.06))
    _array(board, shelves + 1, (0.0, 0.0, (h - t - 0.06) / shelves))
    return b.join(name)


@recipe("books")
def books(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """Rows of books of random thickness, height and lean, filling a `bookshelf` with the same
    width, depth, height and shelves (seeded)."""
    w, d, h = _num(p, "width", 1.0), _num(p, "depth", 0.3), _num(p, "height", 1.8)
    shelves, t = int(p.get("shelves", 5)), _num(p, "thickness", 0.022)
    rng = _rng(p)
    pitch = (h - t - 0.06) / shelves
    b = Parts()
    for k in range(shelves):
        floor = 0.06 + t + k * pitch
        x = -w / 2 + t + 0.01
        while True:
            thick = rng.uniform(0.018, 0.05)
            if x + thick > w / 2 - t - 0.05:
                break
            tall = min(pitch - 0.03, rng.uniform(0.17, 0.3))
            deep = rng.uniform(0.13, 0.2)
            lean = rng.uniform(-4.0, 4.0) if rng.random() < 0.15 else 0.0
            b.cube((thick, deep, tall), (x + thick / 2, d / 2 - 0.01 - deep / 2 - rng.uniform(0, 0.03),
                                         floor + tall / 2), (0.0, lean, 0.0), bevel=0.002)
            x += thick + rng.uniform(0.0, 0.004)
    return b.join(name)


@recipe("radiator")
def radiator(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A column radiator: `sections` fins between two headers, on short feet."""
    w, h, depth = _num(p, "width", 1.0), _num(p, "height", 0.6), _num(p, "depth", 0.09)
    sections = int(p.get("sections", 20))
    b = Parts()
    pitch = w / sections
    fin = b.cube((pitch * 0.6, depth, h - 0.04), (-w / 2 + pitch / 2, 0.0, 0.12 + h / 2), bevel=0.004)
    _array(fin, sections, (pitch, 0.0, 0.0))
    for z in (0.14, 0.1 + h):
        b.tube([(-w / 2 - 0.03, 0.0, z), (w / 2 + 0.03, 0.0, z)], 0.018, 10, "flat")
    for x in (-w / 2 + 0.05, w / 2 - 0.05):
        b.cube((0.03, depth, 0.12), (x, 0.0, 0.06))
    return b.join(name)


@recipe("person")
def person(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A standing person `height` tall (arms slightly apart), facing -y; a warm body-sized target."""
    s = _num(p, "height", 1.75) / 1.75
    b = Parts()
    for sx in (-1, 1):
        x = 0.1 * sx
        b.sphere(1.0, (x, -0.04 * s, 0.045 * s), (0.055 * s, 0.13 * s, 0.045 * s), segments=16, rings=8)
        b.tube([(x, 0.0, 0.07 * s), (x, -0.02 * s, 0.48 * s), (x * 0.95, 0.0, 0.9 * s)],
               [0.055 * s, 0.065 * s, 0.09 * s], 12)
        b.tube([(0.2 * sx * s, 0.0, 1.42 * s), (0.25 * sx * s, 0.02 * s, 1.13 * s), (0.27 * sx * s, -0.04 * s, 0.86 * s)],
               [0.052 * s, 0.045 * s, 0.038 * s], 10)
        b.sphere(0.048 * s, (0.275 * sx * s, -0.045 * s, 0.81 * s), segments=12, rings=6)
    b.sphere(1.0, (0.0, 0.0, 0.93 * s), (0.18 * s, 0.11 * s, 0.1 * s), segments=20, rings=10)
    b.tube([(0.0, 0.0, 0.95 * s), (0.0, 0.0, 1.2 * s), (0.0, 0.0, 1.38 * s)], [0.15 * s, 0.155 * s, 0.17 * s], 16)
    b.sphere(1.0, (0.0, 0.0, 1.42 * s), (0.21 * s, 0.12 * s, 0.07 * s), segments=20, rings=10)
    b.tube([(0.0, 0.0, 1.45 * s), (0.0, 0.0, 1.56 * s)], 0.05 * s, 10, "flat")
    b.sphere(1.0, (0.0, -0.01 * s, 1.65 * s), (0.078 * s, 0.095 * s, 0.112 * s), segments=20, rings=12)
    return b.join(name)


@recipe("fence")
def fence(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A picket fence along X centred on the origin: `posts` posts, two rails, pickets."""
    length, height, posts = _num(p, "length", 6.0), _num(p, "height", 1.0), int(p.get("posts", 5))
    b = Parts()
    post = b.cube((0.09, 0.09, height + 0.1), (-length / 2, 0.0, (height + 0.1) / 2), bevel=0.01)
    _array(post, posts, (length / (posts - 1), 0.0, 0.0))
    for z in (0.3, height - 0.15):
        b.cube((length, 0.04, 0.08), (0.0, 0.05, z))
    pickets = int(length / 0.14)
    picket = b.cone(0.045, 0.045, height, (-length / 2 + 0.07, 0.08, height / 2), (0.0, 0.0, 45.0), segments=4)
    _array(picket, pickets, (length / pickets, 0.0, 0.0))
    return b.join(name)


# --- plants ---------------------------------------------------------------------------------

@recipe("trunk")
def trunk(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A tapering, slightly wandering trunk with `branches` seeded branches in its upper part;
    `base_flare` widens the foot; `bark` (relative) roughens it with a displacement texture."""
    height, radius = _num(p, "height", 1.0), _num(p, "radius", 0.05)
    taper, wobble, n_branches = _num(p, "taper", 0.35), _num(p, "wobble", 0.03), int(p.get("branches", 4))
    rng = _rng(p)
    steps = 9
    z = np.linspace(0.0, height, steps)
    drift = np.cumsum(rng.normal(0.0, wobble * height / steps, (steps, 2)), axis=0)
    drift -= drift[0]
    axis = np.column_stack([drift, z])
    radii = radius * (1.0 - (1.0 - taper) * z / height)
    radii[0] *= 1.0 + _num(p, "base_flare", 0.3)
    b = Parts()
    parts = [b.tube(axis, radii, int(p.get("segments", 14)))]
    golden = math.pi * (3.0 - math.sqrt(5.0))
    for k in range(n_branches):
        u = rng.uniform(0.45, 0.85)
        start = np.array([np.interp(u * height, z, axis[:, i]) for i in range(3)])
        r0 = 0.5 * radius * (1.0 - (1.0 - taper) * u)
        azimuth = k * golden * 2.0 + rng.uniform(-0.4, 0.4)
        elevation = math.radians(rng.uniform(25.0, 55.0))
        length = _num(p, "branch_length", 0.4) * height * rng.uniform(0.7, 1.0)
        pts = [start]
        for j in range(1, 4):
            e = elevation + 0.15 * j
            step = length / 3 * np.array([math.cos(azimuth) * math.cos(e), math.sin(azimuth) * math.cos(e), math.sin(e)])
            pts.append(pts[-1] + step)
        parts.append(b.tube(pts, [r0, r0 * 0.75, r0 * 0.5, r0 * 0.3], 8))
    if _num(p, "bark", 0.0) > 0:
        for part in parts:
            b.displace(part, _num(p, "bark", 0.0) * radius, radius * 1.5, int(p.get("seed", 0)), "VORONOI", 1)
    return b.join(name)


@recipe("leaf_canopy")
def leaf_canopy(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """`count` pointed, creased leaves scattered in an ellipsoidal shell (semi-axes `radii`,
    centred `center_height` above the origin), each facing roughly outwards (seeded)."""
    radii = np.asarray(_vec(p, "radii", (0.4, 0.4, 0.35)))
    center = np.array([0.0, 0.0, _num(p, "center_height", 0.6)])
    length, width = _vec(p, "leaf", (0.09, 0.045))
    count, shell = int(p.get("count", 300)), _num(p, "shell", 0.55)
    rng = _rng(p)
    bm = bmesh.new()
    outline = np.array([[0.0, 0.0, 0.0], [0.35, 0.5, 0.08], [1.0, 0.0, 0.0], [0.35, -0.5, 0.08], [0.4, 0.0, -0.04]])
    for _ in range(count):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        pos = center + radii * direction * rng.uniform(shell, 1.0) ** (1 / 3)
        out = (pos - center) / radii ** 2
        out = out / np.linalg.norm(out) + np.array([0.0, 0.0, 0.6]) + rng.normal(0.0, 0.35, 3)
        out /= np.linalg.norm(out)
        tangent = np.cross(out, rng.normal(size=3))
        tangent /= np.linalg.norm(tangent)
        side = np.cross(out, tangent)
        scale = rng.uniform(0.75, 1.2)
        pts = [pos + scale * (c[0] * length * tangent + c[1] * width * side + c[2] * width * out) for c in outline]
        v = [bm.verts.new(q) for q in pts]
        for tri in ((0, 1, 4), (4, 1, 2), (0, 4, 3), (4, 2, 3)):
            bm.faces.new([v[i] for i in tri])
    b = Parts()
    b.add(bm)
    return b.join(name)


@recipe("conifer")
def conifer(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A spruce-like crown: `tiers` stacked, displaced cones from `crown_base` up to `height`."""
    height, radius, tiers = _num(p, "height", 8.0), _num(p, "radius", 2.0), int(p.get("tiers", 6))
    base = _num(p, "crown_base", 0.15) * height
    rng = _rng(p)
    b = Parts()
    span = height - base
    for i in range(tiers):
        frac = i / tiers
        r = radius * (1.0 - 0.85 * frac) * rng.uniform(0.9, 1.05)
        depth = span * 0.42 * (1.0 - 0.4 * frac)
        bottom = base + span * frac * 0.8
        bm = bmesh.new()
        bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=True, segments=20, radius1=r, radius2=0.0, depth=depth,
                              matrix=_matrix((0.0, 0.0, bottom + depth / 2), (0.0, 0.0, rng.uniform(0, 360))))
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=2, use_grid_fill=True)
        tier = b.add(bm)
        b.displace(tier, 0.3 * r, 0.25 * r, int(p.get("seed", 0)) + i)
    return b.join(name)


@recipe("crown")
def crown(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A broadleaf tree crown: `lobes` overlapping displaced blobs inside semi-axes `radii`,
    its lowest point near z = 0 (seeded)."""
    radii = np.asarray(_vec(p, "radii", (2.0, 2.0, 1.6)))
    lobes, rng = int(p.get("lobes", 7)), _rng(p)
    b = Parts()
    for k in range(lobes):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        center = radii * direction * rng.uniform(0.2, 0.55) + np.array([0.0, 0.0, radii[2]])
        size = radii.min() * rng.uniform(0.45, 0.65)
        lobe = b.ico(size, center, (1.0, 1.0, 0.85), subdivisions=3)
        b.displace(lobe, 0.45 * size, 0.35 * size, int(p.get("seed", 0)) * 31 + k)
    return b.join(name)


# --- food -----------------------------------------------------------------------------------

@recipe("bun")
def bun(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A split hot-dog bun along X: two rounded halves with a gap for the sausage."""
    length, width, height = _num(p, "length", 0.18), _num(p, "width", 0.07), _num(p, "height", 0.055)
    gap = _num(p, "gap", 0.012)
    b = Parts()
    for sy in (-1, 1):
        half = b.sphere(1.0, (0.0, sy * (gap / 2 + width / 4), height / 2),
                        (length / 2, width / 4, height / 2), segments=28, rings=14)
        b.displace(half, 0.06 * height, 0.3 * width, 2 * int(p.get("seed", 0)) + (sy > 0))
    b.cube((length * 0.9, gap + width / 4, height * 0.25), (0.0, 0.0, height * 0.12), bevel=0.005)
    return b.join(name)


@recipe("stick_pile")
def stick_pile(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A heap of `count` square sticks (fries, kindling) within radius `spread` (seeded)."""
    count, length = int(p.get("count", 18)), _num(p, "length", 0.07)
    thick, spread, rng = _num(p, "thickness", 0.009), _num(p, "spread", 0.05), _rng(p)
    b = Parts()
    for k in range(count):
        r, a = spread * math.sqrt(rng.random()), rng.uniform(0, 2 * math.pi)
        z = thick / 2 + thick * 0.9 * (k * 3 // count) + rng.uniform(0.0, thick * 0.3)
        b.cube((length * rng.uniform(0.7, 1.1), thick, thick), (r * math.cos(a), r * math.sin(a), z),
               (rng.uniform(-8, 8), rng.uniform(-8, 8), rng.uniform(0, 180)), bevel=thick * 0.15)
    return b.join(name)


@recipe("grill")
def grill(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A kettle barbecue: bowl, grate, three legs and a rim handle; bowl top at `height`."""
    radius, height = _num(p, "radius", 0.3), _num(p, "height", 0.75)
    b = Parts()
    bowl = [[radius * math.sin(a), height - radius * 0.75 * math.cos(a)] for a in np.linspace(0.05, math.pi / 2, 9)]
    b.lathe([[0.0, bowl[0][1]]] + bowl, 40, 0.012)
    bar = b.tube([(-radius * 0.97, -radius * 0.9, height - 0.04), (radius * 0.97, -radius * 0.9, height - 0.04)],
                 0.005, 6, "flat")
    _array(bar, 13, (0.0, radius * 1.8 / 12, 0.0))
    b.tube([(-radius * 0.97, 0.0, height - 0.045), (radius * 0.97, 0.0, height - 0.045)], 0.006, 6, "flat")
    for k in range(3):
        a = 2 * math.pi * k / 3 + math.pi / 2
        top = (radius * 0.55 * math.cos(a), radius * 0.55 * math.sin(a), height - radius * 0.55)
        foot = (radius * 1.0 * math.cos(a), radius * 1.0 * math.sin(a), 0.02)
        b.tube([foot, top], 0.014, 8, "round")
    b.tube([(radius + 0.01, -0.07, height + 0.005), (radius + 0.06, -0.05, height + 0.01),
            (radius + 0.06, 0.05, height + 0.01), (radius + 0.01, 0.07, height + 0.005)], 0.01, 8)
    return b.join(name)


# --- toy bricks -----------------------------------------------------------------------------

@recipe("toy_bricks")
def toy_bricks(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """Studded toy bricks on a grid: `bricks` [[i, j, layer, nx, ny(, layers)], ...] in stud
    units of `pitch` metres and `layer_height` (default 1.2 pitch, the classic 9.6:8 ratio).
    All bricks of one object share its material, so a preset uses one object per colour."""
    pitch = _num(p, "pitch", 0.032)
    layer = _num(p, "layer_height", 1.2 * pitch)
    gap = 0.0125 * pitch
    b = Parts()
    for entry in p.get("bricks", [[0, 0, 0, 2, 4]]):
        i, j, k, nx, ny = (float(v) for v in entry[:5])
        layers = float(entry[5]) if len(entry) > 5 else 1.0
        x0, y0, z0 = i * pitch, j * pitch, k * layer
        b.cube((nx * pitch - gap, ny * pitch - gap, layers * layer - gap / 2),
               (x0 + nx * pitch / 2, y0 + ny * pitch / 2, z0 + layers * layer / 2), bevel=0.02 * pitch)
        stud_h = 0.2 * pitch
        stud = b.cone(0.3 * pitch, 0.3 * pitch, stud_h, (x0 + pitch / 2, y0 + pitch / 2, z0 + layers * layer + stud_h / 2),
                      segments=16)
        _array(stud, int(nx), (pitch, 0.0, 0.0))
        _array(stud, int(ny), (0.0, pitch, 0.0))
    return b.join(name)


# --- machines and vehicles ------------------------------------------------------------------

@recipe("finned_cylinder")
def finned_cylinder(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A cooling-finned cylinder (engine cylinder, RTG): `fins` ring fins stacked along Z, or
    radial plates when `fin_style` is `radial`."""
    r, h, fins = _num(p, "radius", 0.12), _num(p, "height", 0.3), int(p.get("fins", 10))
    fin_r, fin_t = _num(p, "fin_radius", 0.2), _num(p, "fin_thickness", 0.008)
    b = Parts()
    b.cone(r, r, h, (0.0, 0.0, h / 2), segments=24)
    if str(p.get("fin_style", "rings")) == "radial":
        plate = b.cube((fin_r - r, fin_t, h * 0.9), ((fin_r + r) / 2, 0.0, h / 2))
        b.radial(plate, fins, (0.0, 0.0, 0.0), 360.0 / fins)
    else:
        pitch = h * 0.8 / max(fins - 1, 1)
        ring = b.cone(fin_r, fin_r, fin_t, (0.0, 0.0, h * 0.1), segments=24)
        _array(ring, fins, (0.0, 0.0, pitch))
    b.cone(r * 0.5, r * 0.4, 0.05, (0.0, 0.0, h + 0.025), segments=12)
    return b.join(name)


@recipe("wheel")
def wheel(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A wheel with its axle along X, resting on z = 0: a rounded tyre (or a flat drum when
    `drum` is true) with `treads` tread blocks or grousers, and a hub."""
    r, w = _num(p, "radius", 0.25), _num(p, "width", 0.15)
    treads, depth, hub = int(p.get("treads", 16)), _num(p, "tread_depth", 0.015), _num(p, "hub_radius", 0.35 * r)
    b = Parts()
    if p.get("drum", False):
        profile = [[hub, -w / 2], [r, -w / 2], [r, w / 2], [hub, w / 2]]
    else:
        profile = [[hub * 1.3, -w / 2], [r - 0.2 * w, -w / 2], [r - 0.02 * w, -0.35 * w], [r, 0.0],
                   [r - 0.02 * w, 0.35 * w], [r - 0.2 * w, w / 2], [hub * 1.3, w / 2]]
    b.lathe(profile, 40, 0.01)
    tilt = 0.0 if p.get("drum", False) else 25.0
    block = b.cube((depth * 2, r * 2 * math.pi / treads * 0.45, w * 0.9), (r, 0.0, 0.0), (tilt, 0.0, 0.0))
    b.radial(block, treads, (0.0, 0.0, 0.0), 360.0 / treads)
    b.cone(hub * 1.35, hub * 1.35, w * 0.8, segments=20)
    b.cone(hub * 0.5, hub * 0.45, w * 1.1, segments=12)
    bolt = b.cone(0.12 * hub, 0.12 * hub, w * 0.9, (hub * 0.8, 0.0, 0.0), segments=8)
    b.radial(bolt, 5, (0.0, 0.0, 0.0), 72.0)
    return b.join(name, Matrix.Translation((0.0, 0.0, r)) @ Matrix.Rotation(math.pi / 2, 4, "Y"))


@recipe("tube_frame")
def tube_frame(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A welded tube frame (roll cage of a portable generator): the edges of a box of `size`
    with rounded handles on top."""
    lx, ly, lz = _vec(p, "size", (0.7, 0.5, 0.5))
    r = _num(p, "radius", 0.016)
    b = Parts()
    hx, hy = lx / 2, ly / 2
    for z in (r, lz):
        b.tube([(-hx, -hy, z), (hx, -hy, z), (hx, hy, z), (-hx, hy, z), (-hx, -hy + 1e-3, z)], r, 10, "flat")
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.tube([(sx * hx, sy * hy, r), (sx * hx, sy * hy, lz)], r, 10, "flat")
        b.tube([(sx * hx, -hy, lz), (sx * hx, -hy * 0.6, lz + 0.12), (sx * hx, hy * 0.6, lz + 0.12), (sx * hx, hy, lz)],
               r, 10, "flat")
    return b.join(name)


@recipe("crawler_track")
def crawler_track(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """One crawler track along X: a stadium-shaped frame wrapped in grouser shoes (arrays
    along the straights, radial arrays around the ends), sprocket and idler hubs, rollers."""
    length, width, height = _num(p, "length", 4.2), _num(p, "width", 0.6), _num(p, "height", 0.85)
    pitch, shoe = _num(p, "shoe_pitch", 0.2), _num(p, "shoe_thickness", 0.05)
    r = height / 2 - shoe
    c = length / 2 - height / 2
    zc = shoe + r
    b = Parts()
    bm = bmesh.new()
    loop = ([(c + r * math.cos(a), zc + r * math.sin(a)) for a in np.linspace(math.pi / 2, -math.pi / 2, 13)]
            + [(-c + r * math.cos(a), zc + r * math.sin(a)) for a in np.linspace(-math.pi / 2, -1.5 * math.pi, 13)])
    face = bm.faces.new([bm.verts.new((x, -width / 2, z)) for x, z in loop])
    extruded = bmesh.ops.extrude_face_region(bm, geom=[face])
    bmesh.ops.translate(bm, vec=(0.0, width, 0.0),
                        verts=[v for v in extruded["geom"] if isinstance(v, bmesh.types.BMVert)])
    bmesh.ops.recalc_face_normals(bm, faces=bm.faces[:])
    b.add(bm)
    n_straight = max(1, int(2 * c / pitch) + 1)
    for z in (shoe / 2, zc + r + shoe / 2):
        row = b.cube((pitch * 0.8, width * 1.06, shoe), (-c, 0.0, z), bevel=0.008)
        _array(row, n_straight, (2 * c / (n_straight - 1) if n_straight > 1 else 0.0, 0.0, 0.0))
        grouser = b.cube((0.03, width * 1.06, shoe * 0.8), (-c, 0.0, z + (shoe * 0.8 if z > zc else -shoe * 0.8)))
        _array(grouser, n_straight, (2 * c / (n_straight - 1) if n_straight > 1 else 0.0, 0.0, 0.0))
    n_end = max(2, int(math.pi * (r + shoe / 2) / pitch))
    step = 180.0 / n_end
    for sign in (1, -1):
        angle = math.radians(90.0 - sign * step)
        center = (sign * c, 0.0, zc)
        pad = b.cube((pitch * 0.8, width * 1.06, shoe),
                     (sign * c + (r + shoe / 2) * math.cos(angle), 0.0, zc + (r + shoe / 2) * math.sin(angle)),
                     (0.0, sign * step, 0.0), bevel=0.008)
        b.radial(pad, n_end - 1, center, sign * step, "Y")
        b.cone(r * 0.8, r * 0.8, width * 1.1, center, (90.0, 0.0, 0.0), segments=20)
        b.cone(r * 0.3, r * 0.3, width * 1.25, center, (90.0, 0.0, 0.0), segments=10)
    roller = b.cone(0.12, 0.12, width * 1.04, (-c + 0.45, 0.0, shoe + 0.14), (90.0, 0.0, 0.0), segments=14)
    _array(roller, max(1, int((2 * c - 0.9) / 0.45) + 1), (0.45, 0.0, 0.0))
    return b.join(name)


@recipe("excavator_house")
def excavator_house(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """The excavator's upper structure: swing bearing, deck, engine hood with louvres,
    rounded counterweight and handrails; the boom foot is at +x."""
    length, width = _num(p, "length", 3.2), _num(p, "width", 2.5)
    b = Parts()
    b.cone(1.0, 1.0, 0.3, (0.0, 0.0, 0.15), segments=32)
    b.cube((length, width, 0.3), (0.0, 0.0, 0.45), bevel=0.04)
    hood_x = -length / 2 + 0.75
    b.cube((1.5, width - 0.1, 0.75), (hood_x, 0.0, 0.6 + 0.375), bevel=0.06)
    b.cube((0.5, width, 1.0), (-length / 2 - 0.1, 0.0, 0.6 + 0.5), bevel=0.18)
    for sy in (-1, 1):
        slat = b.cube((0.05, 0.04, 0.45), (hood_x - 0.55, sy * (width / 2 - 0.04), 0.98), (0.0, 0.0, 25.0 * sy))
        _array(slat, 12, (0.1, 0.0, 0.0))
        b.tube([(hood_x - 0.7, sy * (width / 2 - 0.1), 1.35), (hood_x - 0.7, sy * (width / 2 - 0.1), 1.6),
                (hood_x + 0.7, sy * (width / 2 - 0.1), 1.6), (hood_x + 0.7, sy * (width / 2 - 0.1), 1.35)],
               0.02, 8, "flat")
    b.cube((0.8, 0.5, 0.5), (length / 2 - 0.5, 0.0, 0.85), bevel=0.05)
    return b.join(name)


@recipe("cab")
def cab(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """An operator cab frame: a hollow shell whose window openings leave corner pillars. Put
    a slightly smaller glass box inside it to glaze it."""
    lx, ly, lz = _vec(p, "size", (1.6, 1.0, 1.6))
    wall, pillar = _num(p, "wall", 0.05), _num(p, "pillar", 0.1)
    b = Parts()
    shell = b.cube((lx, ly, lz), (0.0, 0.0, lz / 2), bevel=0.04)
    b.subtract(shell, b.cutter((lx - 2 * wall, ly - 2 * wall, lz - 2 * wall), (0.0, 0.0, lz / 2)))
    b.subtract(shell, b.cutter((lx - 2 * pillar, ly * 2, lz * 0.55), (0.0, 0.0, lz * 0.62)))
    b.subtract(shell, b.cutter((lx * 2, ly - 2 * pillar, lz * 0.6), (0.0, 0.0, lz * 0.6)))
    return b.join(name)


@recipe("excavator_arm")
def excavator_arm(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """Boom, stick and bucket (with teeth) of an excavator in the XZ plane, reaching towards
    +x from its foot at the origin, with hydraulic cylinders."""
    boom, stick, bw = _num(p, "boom_length", 5.0), _num(p, "stick_length", 2.6), _num(p, "bucket_width", 1.0)
    b = Parts()

    def beam(start: np.ndarray, angle_deg: float, length: float, section: tuple[float, float]) -> np.ndarray:
        a = math.radians(angle_deg)
        end = start + length * np.array([math.cos(a), 0.0, math.sin(a)])
        b.cube((length + section[1] * 0.6, section[0], section[1]), tuple((start + end) / 2), (0.0, -angle_deg, 0.0),
               bevel=0.03)
        return end

    foot = np.array([0.0, 0.0, 0.3])
    knee = beam(foot, 48.0, boom * 0.55, (0.42, 0.5))
    tip = beam(knee, -18.0, boom * 0.5, (0.38, 0.42))
    wrist = beam(tip, -75.0, stick, (0.3, 0.36))
    b.cube((0.7, bw, 0.55), tuple(wrist + np.array([0.15, 0.0, -0.15])), (0.0, 30.0, 0.0), bevel=0.12)
    tooth = b.cone(0.05, 0.0, 0.18, tuple(wrist + np.array([0.42, -bw / 2 + 0.1, -0.42])), (0.0, 150.0, 0.0),
                   segments=6)
    _array(tooth, 5, (0.0, (bw - 0.2) / 4, 0.0))
    for y in (-0.18, 0.18):
        b.tube([foot + np.array([-0.6, y, -0.1]), foot + np.array([0.9, y, 1.3])], 0.085, 12, "flat")
    b.tube([knee + np.array([-0.2, 0.0, 0.3]), tip + np.array([-0.2, 0.0, 0.35])], 0.075, 12, "flat")
    b.tube([tip + np.array([-0.25, 0.0, 0.0]), wrist + np.array([-0.15, 0.0, 0.45])], 0.065, 12, "flat")
    return b.join(name)


@recipe("rover_body")
def rover_body(name: str, p: dict[str, Any]) -> bpy.types.Object:
    """A six-wheeled rover's chassis, rocker-bogie suspension, mast with camera head and a
    robotic arm. Wheel hubs sit at x in (-wheelbase/2, 0, +wheelbase/2), y = +-track/2,
    z = wheel_radius: place six `wheel` objects there."""
    wb, track, wr = _num(p, "wheelbase", 1.5), _num(p, "track", 1.3), _num(p, "wheel_radius", 0.25)
    lx, ly, lz = _vec(p, "body", (1.3, 0.85, 0.35))
    ride = _num(p, "ride_height", 0.75)
    b = Parts()
    b.cube((lx, ly, lz), (0.0, 0.0, ride + lz / 2), bevel=0.02)
    b.cube((lx + 0.1, ly + 0.1, 0.03), (0.0, 0.0, ride + lz + 0.015), bevel=0.005)
    for sy in (-1, 1):
        y = sy * track / 2
        pivot = np.array([0.1, sy * (ly / 2 + 0.06), ride + 0.1])
        bogie = np.array([-wb * 0.25, y, wr + 0.3])
        b.tube([(wb / 2, y, wr), (wb / 2 - 0.05, y, wr + 0.35), pivot, bogie], 0.03, 10, "round")
        b.tube([(0.0, y, wr), (-0.05, y, wr + 0.25), bogie, (-wb / 2 + 0.05, y, wr + 0.25), (-wb / 2, y, wr)],
               0.028, 10, "round")
        b.tube([pivot, pivot + np.array([0.0, -sy * 0.06, 0.0])], 0.05, 12, "flat")
    top = ride + lz
    mast = np.array([lx / 2 - 0.15, ly / 2 - 0.15, top])
    b.tube([mast, mast + np.array([0.0, 0.0, 0.9])], 0.035, 12, "flat")
    b.cube((0.14, 0.32, 0.16), tuple(mast + np.array([0.02, 0.0, 0.98])), bevel=0.01)
    for dy in (-0.08, 0.08):
        b.cone(0.03, 0.03, 0.06, tuple(mast + np.array([0.11, dy, 0.98])), (0.0, 90.0, 0.0), segments=12)
    arm = [np.array([lx / 2, -0.15, ride + 0.2]), np.array([lx / 2 + 0.35, -0.2, ride + 0.35]),
           np.array([lx / 2 + 0.55, -0.2, ride - 0.05])]
    b.tube(arm, 0.03, 10, "round")
    b.cube((0.16, 0.16, 0.12), tuple(arm[-1] + np.array([0.0, 0.0, -0.08])), bevel=0.01)
    return b.join(name)
