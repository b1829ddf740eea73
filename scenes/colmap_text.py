"""Read COLMAP's text sparse model (cameras.txt, images.txt, points3D.txt) of a capture."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from contracts.errors import DatasetError
from scenes.cameras import intrinsics, quat_to_rotation


def read_colmap_cameras(path: Path) -> dict[int, tuple[int, int, np.ndarray]]:
    """COLMAP cameras.txt → {camera_id: (width, height, K)}; only undistorted pinhole models."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    cams: dict[int, tuple[int, int, np.ndarray]] = {}
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split()
        try:
            cid, model, w, h = int(parts[0]), parts[1], int(parts[2]), int(parts[3])
            params = [float(p) for p in parts[4:]]
        except (IndexError, ValueError) as exc:
            raise DatasetError(f"{path}: line {line_no} is not 'ID MODEL W H PARAMS'") from exc
        if model == "PINHOLE" and len(params) == 4:
            k = intrinsics(*params)
        elif model == "SIMPLE_PINHOLE" and len(params) == 3:
            k = intrinsics(params[0], params[0], params[1], params[2])
        else:
            raise DatasetError(f"{path}: line {line_no}: camera model {model} is not supported; "
                               "undistort to PINHOLE first (colmap image_undistorter)")
        cams[cid] = (w, h, k)
    return cams


def read_colmap_images(path: Path) -> list[tuple[str, int, np.ndarray]]:
    """COLMAP images.txt → [(name, camera_id, OpenCV world-to-camera 4×4)], sorted by name."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    out = []
    for i in range(0, len(lines), 2):
        line = lines[i]
        if not line.strip():
            continue
        parts = line.split()
        try:
            q = np.array([float(v) for v in parts[1:5]])
            t = np.array([float(v) for v in parts[5:8]])
            cid = int(parts[8])
            name = parts[9]
        except (IndexError, ValueError) as exc:
            raise DatasetError(f"{path}: entry {i // 2 + 1} is not 'ID QW QX QY QZ TX TY TZ CAM NAME'") from exc
        if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12 or not np.all(np.isfinite(t)):
            raise DatasetError(f"{path}: entry {i // 2 + 1} ({name}) has an invalid pose")
        v = np.eye(4)
        v[:3, :3] = quat_to_rotation(q)
        v[:3, 3] = t
        out.append((name, cid, v))
    if not out:
        raise DatasetError(f"{path}: no images listed")
    return sorted(out, key=lambda e: e[0])


def read_colmap_points(path: Path) -> np.ndarray:
    """COLMAP points3D.txt → N×3 positions (used to initialise Stage 2)."""
    pts = []
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        try:
            pts.append([float(v) for v in line.split()[1:4]])
        except ValueError as exc:
            raise DatasetError(f"{path}: line {line_no} has a non-numeric position") from exc
    return np.asarray(pts, dtype=np.float64).reshape(-1, 3)
