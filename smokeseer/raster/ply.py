"""PLY export/import in the standard 3DGS layout, so any splat viewer opens our results.

Vertex properties, in order: x y z, nx ny nz, f_dc_*, f_rest_*, opacity, scale_*, rot_*, then any
extra float properties. Encoding as in 3DGS: opacity is a logit, scales are natural logs, rot is
(w, x, y, z), and f_rest is channel-major (all rest coefficients of channel 0, then channel 1...).
Binary little-endian only, written and parsed with numpy (no plyfile dependency).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


@dataclass
class GaussianPly:
    """Gaussians as stored in a 3DGS PLY (numpy, float32 on read)."""

    means: np.ndarray  # [N, 3]
    quats: np.ndarray  # [N, 4] (w, x, y, z), as stored (not re-normalised)
    log_scales: np.ndarray  # [N, 3]
    opacity_logits: np.ndarray  # [N]
    sh: np.ndarray  # [N, K, D] SH coefficients; sh[:, 0] is the DC term, K = (degree+1)^2
    normals: np.ndarray | None = None  # [N, 3]; 3DGS writes zeros
    extra: dict[str, np.ndarray] = field(default_factory=dict)  # further per-Gaussian float props

    @property
    def sh_degree(self) -> int:
        """SH degree implied by the coefficient count."""
        return int(round(self.sh.shape[1] ** 0.5)) - 1


def _column_names(k: int, d: int, extra: dict[str, np.ndarray]) -> list[str]:
    names = ["x", "y", "z", "nx", "ny", "nz"]
    names += [f"f_dc_{i}" for i in range(d)]
    names += [f"f_rest_{i}" for i in range((k - 1) * d)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return names + list(extra)


def _validate(g: GaussianPly) -> tuple[int, int, int]:
    n = g.means.shape[0]
    if g.sh.ndim != 3 or g.sh.shape[0] != n:
        raise ValueError(f"sh must be [N, K, D] with N={n}, got {g.sh.shape}")
    k, d = g.sh.shape[1], g.sh.shape[2]
    if round(k**0.5) ** 2 != k:
        raise ValueError(f"sh must hold (degree+1)^2 coefficients, got K={k}")
    shapes = {"means": (g.means, (n, 3)), "quats": (g.quats, (n, 4)), "log_scales": (g.log_scales, (n, 3)),
              "opacity_logits": (g.opacity_logits, (n,))}
    if g.normals is not None:
        shapes["normals"] = (g.normals, (n, 3))
    for key, arr in g.extra.items():
        shapes[f"extra[{key!r}]"] = (arr, (n,))
    for name, (arr, shape) in shapes.items():
        if tuple(arr.shape) != shape:
            raise ValueError(f"{name} must have shape {shape}, got {tuple(arr.shape)}")
    return n, k, d


def write_ply(path: str | os.PathLike[str], g: GaussianPly) -> None:
    """Write Gaussians as a binary little-endian 3DGS PLY (float32 properties)."""
    n, k, d = _validate(g)
    names = _column_names(k, d, g.extra)
    normals = g.normals if g.normals is not None else np.zeros((n, 3), np.float32)
    rest = np.transpose(g.sh[:, 1:, :], (0, 2, 1)).reshape(n, (k - 1) * d)
    cols = [g.means, normals, g.sh[:, 0, :], rest, g.opacity_logits[:, None], g.log_scales, g.quats]
    cols += [v[:, None] for v in g.extra.values()]
    data = np.concatenate([np.asarray(c, dtype=np.float32).reshape(n, -1) for c in cols], axis=1)
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {name}" for name in names]
    header.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(np.ascontiguousarray(data, dtype="<f4").tobytes())


def _parse_header(f) -> tuple[int, list[tuple[str, str]]]:
    if f.readline().strip() != b"ply":
        raise ValueError("not a PLY file (missing 'ply' magic)")
    n_vertex, props, element = None, [], None
    while True:
        line = f.readline()
        if not line:
            raise ValueError("PLY header has no end_header")
        parts = line.decode("ascii", errors="replace").split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "end_header":
            break
        if parts[0] == "format" and parts[1] != "binary_little_endian":
            raise ValueError(f"only binary_little_endian PLY is supported, got {parts[1]}")
        if parts[0] == "element":
            element = parts[1]
            if element == "vertex":
                n_vertex = int(parts[2])
            elif n_vertex is None or int(parts[2]) != 0:
                raise ValueError(f"unsupported PLY element {element!r} before/besides vertex")
        if parts[0] == "property" and element == "vertex":
            if parts[1] == "list" or parts[1] not in _PLY_TYPES:
                raise ValueError(f"unsupported vertex property type {' '.join(parts[1:-1])}")
            props.append((parts[-1], "<" + _PLY_TYPES[parts[1]]))
    if n_vertex is None:
        raise ValueError("PLY has no vertex element")
    return n_vertex, props


def read_ply(path: str | os.PathLike[str]) -> GaussianPly:
    """Read a binary little-endian 3DGS PLY (ours or any 3DGS trainer's)."""
    with open(path, "rb") as f:
        n, props = _parse_header(f)
        dtype = np.dtype(props)
        raw = np.frombuffer(f.read(n * dtype.itemsize), dtype=dtype, count=n)
    names = [p[0] for p in props]

    def cols(keys: list[str]) -> np.ndarray:
        missing = [key for key in keys if key not in names]
        if missing:
            raise ValueError(f"PLY lacks required properties {missing}")
        return np.stack([raw[key].astype(np.float32) for key in keys], axis=1) if keys else np.zeros((n, 0), np.float32)

    def numbered(prefix: str) -> list[str]:
        found = sorted((name for name in names if name.startswith(prefix)), key=lambda s: int(s[len(prefix):]))
        return found

    dc = cols(numbered("f_dc_"))
    d = dc.shape[1]
    if d == 0:
        raise ValueError("PLY lacks f_dc_* colour properties")
    rest_names = numbered("f_rest_")
    if len(rest_names) % d:
        raise ValueError(f"{len(rest_names)} f_rest_* properties do not divide into {d} channels")
    rest = cols(rest_names).reshape(n, d, len(rest_names) // d).transpose(0, 2, 1)
    sh = np.concatenate([dc[:, None, :], rest], axis=1)
    known = {"x", "y", "z", "nx", "ny", "nz", "opacity", *rest_names, *numbered("f_dc_"),
             *(f"scale_{i}" for i in range(3)), *(f"rot_{i}" for i in range(4))}
    has_normals = all(key in names for key in ("nx", "ny", "nz"))
    return GaussianPly(
        means=cols(["x", "y", "z"]),
        quats=cols([f"rot_{i}" for i in range(4)]),
        log_scales=cols([f"scale_{i}" for i in range(3)]),
        opacity_logits=cols(["opacity"])[:, 0],
        sh=np.ascontiguousarray(sh),
        normals=cols(["nx", "ny", "nz"]) if has_normals else None,
        extra={name: raw[name].astype(np.float32) for name in names if name not in known},
    )
