"""Read COLMAP's binary sparse model (cameras.bin, images.bin, points3D.bin).

The official SmokeSeer real-data layout stores its poses only in this form (its text reader
never sets the frame number). Layouts follow COLMAP's documented little-endian records.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.errors import DatasetError
from scenes.cameras import quat_to_rotation

CAMERA_MODELS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
    4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
}


@dataclass
class ColmapCamera:
    camera_id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass
class ColmapImage:
    image_id: int
    qvec: np.ndarray
    tvec: np.ndarray
    camera_id: int
    name: str

    def viewmat(self) -> np.ndarray:
        """OpenCV world-to-camera 4×4 (COLMAP stores exactly that, rotation as w, x, y, z)."""
        v = np.eye(4)
        v[:3, :3] = quat_to_rotation(self.qvec)
        v[:3, 3] = self.tvec
        return v


class _Reader:
    """Sequential little-endian reads that name the file when it ends early."""

    def __init__(self, path: Path) -> None:
        if not path.is_file():
            raise DatasetError(f"{path}: missing file")
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise DatasetError(f"{self.path}: truncated at byte {self.pos} (not a COLMAP binary model?)")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def cstring(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise DatasetError(f"{self.path}: truncated image name at byte {self.pos}")
        raw = self.data[self.pos:end]
        self.pos = end + 1
        return raw.decode("utf-8", errors="replace")


def read_cameras_bin(path: Path) -> dict[int, ColmapCamera]:
    r = _Reader(path)
    (n,) = r.take("Q")
    cams: dict[int, ColmapCamera] = {}
    for _ in range(n):
        cid, model_id, w, h = r.take("iiQQ")
        if model_id not in CAMERA_MODELS:
            raise DatasetError(f"{path}: camera {cid} has unknown model id {model_id}")
        name, nparams = CAMERA_MODELS[model_id]
        cams[cid] = ColmapCamera(cid, name, int(w), int(h), np.array(r.take("d" * nparams)))
    return cams


def read_images_bin(path: Path) -> list[ColmapImage]:
    r = _Reader(path)
    (n,) = r.take("Q")
    out = []
    for _ in range(n):
        iid, qw, qx, qy, qz, tx, ty, tz, cid = r.take("idddddddi")
        name = r.cstring()
        (npts,) = r.take("Q")
        r.take("ddq" * npts)
        q, t = np.array([qw, qx, qy, qz]), np.array([tx, ty, tz])
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))) or np.linalg.norm(q) < 1e-12:
            raise DatasetError(f"{path}: image {name!r} has an invalid pose")
        out.append(ColmapImage(iid, q, t, cid, name))
    return out


def read_points3d_bin(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """N×3 positions and N×3 uint8 colours."""
    r = _Reader(path)
    (n,) = r.take("Q")
    xyz = np.zeros((n, 3))
    rgb = np.zeros((n, 3), dtype=np.uint8)
    for i in range(n):
        vals = r.take("QdddBBBd")
        xyz[i] = vals[1:4]
        rgb[i] = vals[4:7]
        (track,) = r.take("Q")
        r.take("ii" * track)
    return xyz, rgb
