"""Dark channel prior on the analytic haze model I = J·t + A·(1−t)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from PIL import Image
from scipy.ndimage import gaussian_filter

from eval.dehaze import (DarkChannelPrior, Dehazer, available_dehazers, dehaze_dataset, get_dehazer,
                         guided_filter, register_dehazer)


def _scene(h: int = 96, w: int = 128, seed: int = 0) -> np.ndarray:
    """A haze-free image that obeys the dark-channel prior: saturated colour patches
    (one channel near 0 in every patch) with shading."""
    rng = np.random.default_rng(seed)
    blocks = rng.integers(0, 3, size=(h // 16 + 1, w // 16 + 1))
    dark = np.kron(blocks, np.ones((16, 16)))[:h, :w].astype(int)
    j = 0.2 + 0.6 * rng.random((h, w, 3))
    j = gaussian_filter(j, (1.5, 1.5, 0))
    for c in range(3):
        j[..., c] = np.where(dark == c, 0.01, j[..., c])
    return j


def _haze(j: np.ndarray, t: np.ndarray, a: np.ndarray) -> np.ndarray:
    return j * t[..., None] + a * (1.0 - t[..., None])


def test_dcp_inverts_analytic_haze() -> None:
    j = _scene()
    h, w = j.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    t = 0.35 + 0.4 * xx / w + 0.1 * np.sin(yy / 15.0)  # smooth, 0.25..0.85
    t[:12] = 0.02  # a band of dense smoke: DCP reads the airlight there (He et al.'s assumption)
    a = np.array([0.85, 0.88, 0.9])
    hazy = _haze(j, t, a)
    dcp = DarkChannelPrior(linearize=False, patch=7)
    j_hat, t_hat, a_hat = dcp.dehaze_linear(hazy)
    m = slice(12, None)  # J is unrecoverable under t = 0.02; score the rest
    err_in = np.sqrt(np.mean((hazy[m] - j[m]) ** 2))
    err_out = np.sqrt(np.mean((j_hat[m] - j[m]) ** 2))
    assert err_out < 0.35 * err_in
    assert np.abs(a_hat - a).max() < 0.02
    # omega = 0.95 keeps 5 % haze on purpose: t_hat = 1 - 0.95(1 - t) up to filtering
    assert np.median(np.abs(t_hat - (1 - 0.95 * (1 - t)))[m]) < 0.06


def test_dcp_on_srgb_reduces_error_and_keeps_range() -> None:
    j = _scene(seed=1)
    t = np.full(j.shape[:2], 0.5)
    t[:12] = 0.02
    hazy_lin = _haze(j, t, np.array([0.9, 0.9, 0.9]))
    to_srgb = lambda x: np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)  # noqa: E731
    out = get_dehazer("dcp")(to_srgb(hazy_lin))
    assert out.shape == j.shape and out.min() >= 0.0 and out.max() <= 1.0
    m = slice(12, None)
    assert np.abs(out - to_srgb(j))[m].mean() < 0.5 * np.abs(to_srgb(hazy_lin) - to_srgb(j))[m].mean()


def test_guided_filter_preserves_linear_relation() -> None:
    rng = np.random.default_rng(3)
    guide = gaussian_filter(rng.random((40, 50)), 2)
    src = 2.0 * guide + 0.3  # exactly linear in the guide: the filter must return it
    out = guided_filter(guide, src, radius=4, eps=1e-8)
    assert np.abs(out - src).max() < 1e-3


def test_registry_and_validation() -> None:
    assert "dcp" in available_dehazers()
    with pytest.raises(ValueError, match="dehazer"):
        get_dehazer("convir")
    with pytest.raises(ValueError, match="omega"):
        DarkChannelPrior(omega=1.5)

    class Identity:
        name = "identity"

        def __call__(self, rgb: np.ndarray) -> np.ndarray:
            return rgb

    register_dehazer("identity", Identity)
    assert isinstance(get_dehazer("identity"), Dehazer)


def _write_dataset(root) -> None:
    rng = np.random.default_rng(0)
    for sub in ("rgb/smoky", "rgb/clean"):
        (root / sub).mkdir(parents=True)
        for i in range(2):
            Image.fromarray((rng.random((24, 32, 3)) * 255).astype(np.uint8)).save(root / sub / f"{i:04d}.png")
    (root / "dataset.json").write_text(json.dumps({"format": "smokeseer-synth-dataset", "format_version": 1}))
    (root / "transforms_rgb.json").write_text(json.dumps({"frames": []}))


def test_dehaze_dataset_copies_and_leaves_source(tmp_path) -> None:
    src, dst = tmp_path / "src", tmp_path / "dst"
    _write_dataset(src)
    before = (src / "rgb/smoky/0000.png").read_bytes()
    dehaze_dataset(src, dst, DarkChannelPrior())
    assert (src / "rgb/smoky/0000.png").read_bytes() == before
    assert json.loads((src / "dataset.json").read_text()).get("dehazed_by") is None
    meta = json.loads((dst / "dataset.json").read_text())
    assert meta["dehazed_by"]["name"] == "dcp" and meta["format_version"] == 1
    assert sorted(p.name for p in (dst / "rgb/smoky").iterdir()) == ["0000.png", "0001.png"]
    assert (dst / "rgb/smoky/0000.png").read_bytes() != before
    assert os.path.samefile(src / "rgb/clean/0001.png", dst / "rgb/clean/0001.png") or \
        (src / "rgb/clean/0001.png").read_bytes() == (dst / "rgb/clean/0001.png").read_bytes()
    with pytest.raises(ValueError, match="src"):
        dehaze_dataset(tmp_path / "missing", tmp_path / "x", DarkChannelPrior())
