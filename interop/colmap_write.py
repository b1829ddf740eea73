"""Write COLMAP's binary sparse model, the only form the official SmokeSeer reader trusts.

Record layouts are COLMAP's documented little-endian ones; ``scenes.colmap_binary`` reads
them back and a test checks the two against each other and against hand-packed bytes.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1}


@dataclass
class CameraRecord:
    camera_id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclass
class ImageRecord:
    image_id: int
    viewmat: np.ndarray
    camera_id: int
    name: str


def rotation_to_qvec(r: np.ndarray) -> np.ndarray:
    """Rotation matrix → unit quaternion (w, x, y, z) with w >= 0 (Shepperd's method)."""
    m = np.asarray(r, dtype=np.float64)
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def cameras_bin(cameras: list[CameraRecord]) -> bytes:
    out = [struct.pack("<Q", len(cameras))]
    for c in cameras:
        out.append(struct.pack("<iiQQ", c.camera_id, MODEL_IDS[c.model], c.width, c.height))
        out.append(struct.pack("<" + "d" * len(c.params), *c.params))
    return b"".join(out)


def images_bin(images: list[ImageRecord]) -> bytes:
    """Registered images without 2D keypoints (the official reader does not use them)."""
    out = [struct.pack("<Q", len(images))]
    for im in images:
        q = rotation_to_qvec(im.viewmat[:3, :3])
        t = im.viewmat[:3, 3]
        out.append(struct.pack("<idddddddi", im.image_id, *q, *t, im.camera_id))
        out.append(im.name.encode("utf-8") + b"\0")
        out.append(struct.pack("<Q", 0))
    return b"".join(out)


def points3d_bin(xyz: np.ndarray, rgb: np.ndarray) -> bytes:
    """Points with empty tracks and zero reprojection error."""
    out = [struct.pack("<Q", len(xyz))]
    for i, (p, c) in enumerate(zip(np.asarray(xyz, dtype=np.float64), np.asarray(rgb, dtype=np.uint8))):
        out.append(struct.pack("<QdddBBBdQ", i + 1, *p, *c, 0.0, 0))
    return b"".join(out)


def write_model(sparse: Path, cameras: list[CameraRecord], images: list[ImageRecord],
                xyz: np.ndarray, rgb: np.ndarray) -> None:
    sparse.mkdir(parents=True, exist_ok=True)
    (sparse / "cameras.bin").write_bytes(cameras_bin(cameras))
    (sparse / "images.bin").write_bytes(images_bin(images))
    (sparse / "points3D.bin").write_bytes(points3d_bin(xyz, rgb))
