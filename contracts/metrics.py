"""Image, depth and mask metrics with the conventions the paper's numbers use.

Images are H×W×C (or H×W) float arrays in [0, 1]; torch tensors are accepted and
converted. Every function validates its input and raises a ValueError naming the
offending argument, so a bad render never turns into a silently wrong table digit.
"""

from __future__ import annotations

import importlib.util
import io
import math
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from scipy import ndimage

PSNR_CAP_DB = 100.0
"""PSNR reported for a (near-)perfect match: MSE is floored at max_val²·1e-10 so
identical images give a finite, JSON-safe 100 dB instead of +inf."""

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def _as_array(x: Any, name: str) -> np.ndarray:
    """Convert numpy/torch input to float64 numpy, rejecting what cannot be scored."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    arr = np.asarray(x)
    if arr.dtype == bool or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name}: expected a numeric array, got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or Inf")
    return arr


def _image_pair(pred: Any, target: Any) -> tuple[np.ndarray, np.ndarray]:
    p = _as_array(pred, "pred")
    t = _as_array(target, "target")
    if p.ndim not in (2, 3):
        raise ValueError(f"pred: expected H×W or H×W×C, got shape {p.shape}")
    if p.shape != t.shape:
        raise ValueError(f"target: shape {t.shape} does not match pred shape {p.shape}")
    if p.size == 0:
        raise ValueError("pred: empty image")
    if p.ndim == 2:
        p, t = p[..., None], t[..., None]
    return p, t


def psnr(pred: Any, target: Any, max_val: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of one image pair (average per image, not per pixel pool)."""
    _check_max_val(max_val)
    p, t = _image_pair(pred, target)
    return _psnr_of_mse(float(np.mean((p - t) ** 2)), max_val)


def psnr_where(pred: Any, target: Any, where: Any, max_val: float = 1.0) -> float | None:
    """PSNR in dB of one image pair over the pixels ``where`` (H×W, true or > 0.5) marks, every
    channel of them; None where it marks none."""
    _check_max_val(max_val)
    p, t = _image_pair(pred, target)
    w = np.asarray(where)
    if w.shape != p.shape[:2]:
        raise ValueError(f"where: shape {w.shape} does not match the image's {p.shape[:2]}")
    inside = w > 0.5
    if not inside.any():
        return None
    return _psnr_of_mse(float(np.mean((p[inside] - t[inside]) ** 2)), max_val)


def _check_max_val(max_val: float) -> None:
    if not (max_val > 0 and math.isfinite(max_val)):
        raise ValueError(f"max_val: must be positive and finite, got {max_val}")


def _psnr_of_mse(mse: float, max_val: float) -> float:
    mse = max(mse, max_val**2 * 10 ** (-PSNR_CAP_DB / 10))
    return float(10.0 * math.log10(max_val**2 / mse))


def _gaussian_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    x = np.arange(size, dtype=np.float64) - size // 2
    g = np.exp(-(x**2) / (2.0 * sigma**2))
    return g / g.sum()


def _blur_zero_pad(img: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Separable 2D Gaussian filter with zero padding, the padding 3DGS's conv2d uses."""
    out = ndimage.correlate1d(img, kernel, axis=0, mode="constant", cval=0.0)
    return ndimage.correlate1d(out, kernel, axis=1, mode="constant", cval=0.0)


def ssim_map_3dgs(pred: Any, target: Any) -> np.ndarray:
    """Per-pixel, per-channel SSIM map (H×W×C) with the 3DGS window and zero padding."""
    p, t = _image_pair(pred, target)
    k = _gaussian_1d()
    out = np.empty_like(p)
    for c in range(p.shape[2]):
        x, y = p[..., c], t[..., c]
        mu_x, mu_y = _blur_zero_pad(x, k), _blur_zero_pad(y, k)
        sxx = _blur_zero_pad(x * x, k) - mu_x**2
        syy = _blur_zero_pad(y * y, k) - mu_y**2
        sxy = _blur_zero_pad(x * y, k) - mu_x * mu_y
        num = (2 * mu_x * mu_y + SSIM_C1) * (2 * sxy + SSIM_C2)
        den = (mu_x**2 + mu_y**2 + SSIM_C1) * (sxx + syy + SSIM_C2)
        out[..., c] = num / den
    return out


def ssim_3dgs(pred: Any, target: Any) -> float:
    """SSIM as 3DGS reports it: mean over the full zero-padded map, all channels.

    skimage and most libraries crop the border instead, which reads lower on small
    images; using this convention keeps our numbers comparable to the paper's.
    """
    return float(np.mean(ssim_map_3dgs(pred, target)))


def depth_errors(pred: Any, gt: Any) -> dict[str, float]:
    """AbsRel and RMSE (metres) of planar depth over pixels with ground truth > 0."""
    p = _as_array(pred, "pred")
    g = _as_array(gt, "gt")
    if p.shape != g.shape:
        raise ValueError(f"gt: shape {g.shape} does not match pred shape {p.shape}")
    valid = g > 0
    if not np.any(valid):
        raise ValueError("gt: no pixel with depth > 0, depth error is undefined")
    d = p[valid] - g[valid]
    return {
        "absrel": float(np.mean(np.abs(d) / g[valid])),
        "rmse": float(np.sqrt(np.mean(d**2))),
    }


def mask_iou(pred: np.ndarray, gt: np.ndarray) -> float | None:
    """Intersection over union of two binary masks (non-zero = inside); None if both are empty."""
    p = np.asarray(pred.detach().cpu().numpy() if hasattr(pred, "detach") else pred)
    g = np.asarray(gt.detach().cpu().numpy() if hasattr(gt, "detach") else gt)
    if p.shape != g.shape:
        raise ValueError(f"gt: shape {g.shape} does not match pred shape {p.shape}")
    p, g = p != 0, g != 0
    union = int(np.count_nonzero(p | g))
    if union == 0:
        return None
    return float(np.count_nonzero(p & g) / union)


# ---------------------------------------------------------------- LPIPS (offline only)


@dataclass(frozen=True)
class _TrunkSpec:
    """A torchvision `features` Sequential: conv layers by index, pools by index, taps after ReLUs."""

    convs: dict[int, tuple[int, int, int, int, int]]  # index -> (in, out, kernel, stride, pad)
    pools: dict[int, tuple[int, int]]  # index -> (kernel, stride)
    taps: tuple[int, ...]  # indices of the ReLUs whose outputs LPIPS compares
    checkpoint: str  # torchvision's file name in hub/checkpoints


def _vgg16_spec() -> _TrunkSpec:
    convs: dict[int, tuple[int, int, int, int, int]] = {}
    pools: dict[int, tuple[int, int]] = {}
    idx, cin = 0, 3
    for block in ((64, 64), (128, 128), (256, 256, 256), (512, 512, 512), (512, 512, 512)):
        for cout in block:
            convs[idx] = (cin, cout, 3, 1, 1)
            cin, idx = cout, idx + 2
        pools[idx] = (2, 2)
        idx += 1
    return _TrunkSpec(convs, pools, (3, 8, 15, 22, 29), "vgg16-397923af.pth")


_TRUNKS: dict[str, _TrunkSpec] = {
    "alex": _TrunkSpec(
        convs={0: (3, 64, 11, 4, 2), 3: (64, 192, 5, 1, 2), 6: (192, 384, 3, 1, 1),
               8: (384, 256, 3, 1, 1), 10: (256, 256, 3, 1, 1)},
        pools={2: (3, 2), 5: (3, 2), 12: (3, 2)},
        taps=(1, 4, 7, 9, 11),
        checkpoint="alexnet-owt-7be5be79.pth",
    ),
    "vgg": _vgg16_spec(),
}

# LPIPS input normalisation (the constants of its ScalingLayer), applied to [-1, 1] images.
_LPIPS_SHIFT = (-0.030, -0.088, -0.188)
_LPIPS_SCALE = (0.458, 0.448, 0.450)


def _checkpoint_dirs() -> list[Path]:
    dirs = []
    if os.environ.get("TORCH_HOME"):
        dirs.append(Path(os.environ["TORCH_HOME"]) / "hub" / "checkpoints")
    dirs.append(Path.home() / ".cache" / "torch" / "hub" / "checkpoints")
    return dirs


def find_backbone(net: str, weights_path: str | None = None) -> Path | None:
    """Explicit path (file or folder), then $TORCH_HOME/hub/checkpoints, then ~/.cache/torch."""
    name = _TRUNKS[net].checkpoint
    if weights_path is not None:
        p = Path(weights_path).expanduser()
        if p.is_dir():
            p = p / name
        return p if p.is_file() else None
    for d in _checkpoint_dirs():
        if (d / name).is_file():
            return d / name
    return None


def find_heads(net: str, heads_path: str | None = None) -> Path | None:
    """LPIPS v0.1 linear heads: an explicit .pth or lpips wheel, the installed `lpips`
    package's data files (located without importing it: it imports torchvision), or
    `lpips_v0.1_{net}.pth` in the checkpoint folders."""
    if heads_path is not None:
        p = Path(heads_path).expanduser()
        return p if p.is_file() else None
    spec = importlib.util.find_spec("lpips")
    if spec is not None and spec.submodule_search_locations:
        for loc in spec.submodule_search_locations:
            p = Path(loc) / "weights" / "v0.1" / f"{net}.pth"
            if p.is_file():
                return p
    for d in _checkpoint_dirs():
        if (d / f"lpips_v0.1_{net}.pth").is_file():
            return d / f"lpips_v0.1_{net}.pth"
    return None


def _load_state(path: Path, member: str | None = None) -> dict[str, Any]:
    import torch

    if path.suffix == ".whl":
        with zipfile.ZipFile(path) as z:
            data = io.BytesIO(z.read(member or ""))
        return torch.load(data, map_location="cpu", weights_only=True)
    return torch.load(path, map_location="cpu", weights_only=True)


def _build_lpips(net: str, backbone: dict[str, Any], heads: dict[str, Any]) -> Callable[[Any, Any], float]:
    import torch
    import torch.nn.functional as F

    spec = _TRUNKS[net]
    convs = {}
    for i, (cin, cout, _k, _s, _p) in spec.convs.items():
        w, b = backbone.get(f"features.{i}.weight"), backbone.get(f"features.{i}.bias")
        if w is None or b is None:
            raise ValueError(f"weights_path: backbone state dict lacks features.{i}.weight/bias")
        if tuple(w.shape[:2]) != (cout, cin):
            raise ValueError(f"weights_path: features.{i}.weight has shape {tuple(w.shape)}, "
                             f"expected ({cout}, {cin}, ...) for {net}")
        convs[i] = (w.float(), b.float())
    lins = []
    for k, tap in enumerate(spec.taps):
        w = heads.get(f"lin{k}.model.1.weight")
        cout = spec.convs[tap - 1][1]
        if w is None or tuple(w.shape) != (1, cout, 1, 1):
            raise ValueError(f"heads_path: lin{k}.model.1.weight missing or not shaped (1, {cout}, 1, 1)")
        lins.append(w.float())
    shift = torch.tensor(_LPIPS_SHIFT, device="cpu").view(1, 3, 1, 1)  # the images come from numpy: CPU
    scale = torch.tensor(_LPIPS_SCALE, device="cpu").view(1, 3, 1, 1)
    last = max(spec.taps)

    def features(x: torch.Tensor) -> list[torch.Tensor]:
        outs = []
        for i in range(last + 1):
            if i in convs:
                _cin, _cout, _k, s, p = spec.convs[i]
                x = F.conv2d(x, convs[i][0], convs[i][1], stride=s, padding=p)
            elif i in spec.pools:
                x = F.max_pool2d(x, *spec.pools[i])
            else:
                x = F.relu(x)
                if i in spec.taps:
                    outs.append(x)
        return outs

    def score(pred: Any, target: Any) -> float:
        p, t = _image_pair(pred, target)
        if p.shape[2] != 3:
            raise ValueError(f"pred: LPIPS needs 3-channel RGB, got {p.shape[2]} channels")
        batch = torch.from_numpy(np.stack([p, t]).transpose(0, 3, 1, 2).astype(np.float32))
        batch = ((batch * 2.0 - 1.0) - shift) / scale
        with torch.no_grad():
            try:
                feats = features(batch)
            except RuntimeError:  # a pooling window larger than the feature map
                raise ValueError(f"pred: {p.shape[0]}x{p.shape[1]} px is too small for LPIPS-{net}") from None
            total = torch.zeros((), device=batch.device)
            for f, w in zip(feats, lins):
                f = f / (torch.sqrt(torch.sum(f * f, dim=1, keepdim=True)) + 1e-10)
                d = (f[0:1] - f[1:2]) ** 2
                total = total + F.conv2d(d, w).mean()
        return float(total)

    return score


def load_lpips(
    weights_path: str | None = None, net: str = "alex", heads_path: str | None = None
) -> tuple[Callable[[Any, Any], float] | None, str]:
    """Build an LPIPS scorer from weights on local disk, never downloading.

    Returns (scorer, status). The scorer takes two H×W×3 images in [0, 1]. When the
    backbone or heads are missing the scorer is None and the status starts with
    "skipped:" and says where to put the files.
    """
    if net not in _TRUNKS:
        raise ValueError(f"net: must be one of {sorted(_TRUNKS)}, got {net!r}")
    backbone = find_backbone(net, weights_path)
    if backbone is None:
        where = weights_path or " or ".join(str(d) for d in _checkpoint_dirs())
        return None, (f"skipped: no weights ({_TRUNKS[net].checkpoint} not found in {where}; "
                      "put torchvision's file there or pass --lpips-weights)")
    heads = find_heads(net, heads_path)
    if heads is None:
        return None, (f"skipped: no weights (LPIPS v0.1 {net} heads not found; "
                      "`pip install --no-deps lpips` or pass --lpips-heads)")
    member = f"lpips/weights/v0.1/{net}.pth" if heads.suffix == ".whl" else None
    scorer = _build_lpips(net, _load_state(backbone), _load_state(heads, member))
    return scorer, f"ok: {net} from {backbone}"
