"""3DGS PLY layout: round trip, exact on-disk layout, and reading files from other writers."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from smokeseer.raster import GaussianPly, read_ply, write_ply


def random_gaussians(n: int, degree: int, d: int = 3, seed: int = 0) -> GaussianPly:
    rng = np.random.default_rng(seed)
    f = lambda *shape: rng.normal(size=shape).astype(np.float32)  # noqa: E731
    return GaussianPly(means=f(n, 3), quats=f(n, 4), log_scales=f(n, 3), opacity_logits=f(n),
                       sh=f(n, (degree + 1) ** 2, d), normals=f(n, 3), extra={"thermal": f(n)})


@pytest.mark.parametrize("degree,d", [(0, 3), (3, 3), (2, 1)])
def test_round_trip(tmp_path: Path, degree: int, d: int) -> None:
    g = random_gaussians(17, degree, d)
    path = tmp_path / "g.ply"
    write_ply(path, g)
    back = read_ply(path)
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh", "normals"):
        np.testing.assert_array_equal(getattr(back, name), getattr(g, name), err_msg=name)
    np.testing.assert_array_equal(back.extra["thermal"], g.extra["thermal"])
    assert back.sh_degree == degree


def test_on_disk_layout_is_standard_3dgs(tmp_path: Path) -> None:
    g = random_gaussians(3, 3)
    path = tmp_path / "g.ply"
    write_ply(path, GaussianPly(g.means, g.quats, g.log_scales, g.opacity_logits, g.sh))
    raw = path.read_bytes()
    head, body = raw.split(b"end_header\n", 1)
    lines = head.decode().splitlines()
    assert lines[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 3"]
    names = [ln.split()[2] for ln in lines[3:]]
    assert all(ln.split()[1] == "float" for ln in lines[3:])
    expected = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
                + [f"f_rest_{i}" for i in range(45)]
                + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    assert names == expected
    rows = np.frombuffer(body, dtype="<f4").reshape(3, len(names))
    col = {name: i for i, name in enumerate(names)}
    i = 2
    assert rows[i, col["nx"]] == 0.0
    assert rows[i, col["f_dc_1"]] == g.sh[i, 0, 1]
    # Channel-major f_rest: f_rest_{c*15 + j} holds coefficient j+1 of channel c.
    for c in range(3):
        for j in range(15):
            assert rows[i, col[f"f_rest_{c * 15 + j}"]] == g.sh[i, j + 1, c]
    assert rows[i, col["opacity"]] == g.opacity_logits[i]
    assert rows[i, col["rot_0"]] == g.quats[i, 0]  # w first
    assert rows[i, col["scale_2"]] == g.log_scales[i, 2]


def test_reads_foreign_writer_with_doubles_comments_and_other_order(tmp_path: Path) -> None:
    """A file in another valid form: comment lines, doubles, a uchar, no normals, shuffled order."""
    props = [("opacity", "double"), ("x", "float"), ("y", "float"), ("z", "float"), ("f_dc_0", "float"),
             ("f_dc_1", "float"), ("f_dc_2", "float"), ("red", "uchar"), ("scale_0", "float"),
             ("scale_1", "float"), ("scale_2", "float"), ("rot_0", "float"), ("rot_1", "float"),
             ("rot_2", "float"), ("rot_3", "float")]
    header = ["ply", "format binary_little_endian 1.0", "comment made by hand", "element vertex 2"]
    header += [f"property {t} {name}" for name, t in props] + ["end_header"]
    fmt = "<d" + "fff" + "fff" + "B" + "fff" + "ffff"
    rows = [(-1.5, 1, 2, 3, 0.1, 0.2, 0.3, 7, -3, -4, -5, 1, 0, 0, 0),
            (2.5, 4, 5, 6, 0.4, 0.5, 0.6, 9, -6, -7, -8, 0, 1, 0, 0)]
    path = tmp_path / "foreign.ply"
    path.write_bytes(("\n".join(header) + "\n").encode() + b"".join(struct.pack(fmt, *r) for r in rows))
    g = read_ply(path)
    np.testing.assert_allclose(g.means, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_allclose(g.opacity_logits, [-1.5, 2.5])
    np.testing.assert_allclose(g.sh[:, 0], [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]], rtol=1e-6)
    assert g.sh.shape == (2, 1, 3) and g.normals is None
    np.testing.assert_allclose(g.quats[1], [0, 1, 0, 0])
    np.testing.assert_array_equal(g.extra["red"], [7, 9])


def test_rejects_unsupported_files(tmp_path: Path) -> None:
    path = tmp_path / "a.ply"
    path.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(ValueError, match="binary_little_endian"):
        read_ply(path)
    path.write_bytes(b"not a ply\n")
    with pytest.raises(ValueError, match="PLY"):
        read_ply(path)
    g = random_gaussians(4, 1)
    with pytest.raises(ValueError, match="quats"):
        write_ply(path, GaussianPly(g.means, g.quats[:, :3], g.log_scales, g.opacity_logits, g.sh))
