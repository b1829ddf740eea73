"""Metrics against independent references: skimage, torch conv2d, closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from contracts import metrics
from contracts.metrics import depth_errors, load_lpips, mask_iou, psnr, psnr_where, ssim_3dgs, ssim_map_3dgs


def _pair(seed: int = 0, shape: tuple[int, ...] = (40, 56, 3)) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    base = ndimage_smooth(rng.random(shape))
    noisy = np.clip(base + 0.08 * rng.standard_normal(shape), 0.0, 1.0)
    return noisy, base


def ndimage_smooth(x: np.ndarray) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    sig = (2.0, 2.0, 0.0) if x.ndim == 3 else 2.0
    return gaussian_filter(x, sig)


def test_psnr_analytic_constant_offset() -> None:
    a = np.full((8, 9, 3), 0.5)
    b = a + 0.1  # MSE = 0.01 exactly -> 20 dB
    assert psnr(a, b) == pytest.approx(20.0, abs=1e-9)
    assert psnr(a * 255, b * 255, max_val=255.0) == pytest.approx(20.0, abs=1e-9)


def test_psnr_matches_skimage_and_accepts_torch() -> None:
    p, t = _pair(1)
    ref = peak_signal_noise_ratio(t, p, data_range=1.0)
    assert psnr(p, t) == pytest.approx(ref, abs=1e-9)
    assert psnr(torch.from_numpy(p), torch.from_numpy(t)) == pytest.approx(ref, abs=1e-9)


def test_psnr_where_scores_only_the_marked_pixels() -> None:
    p, t = _pair(3)
    where = np.zeros(p.shape[:2], dtype=bool)
    where[5:20, 10:40] = True
    far = p.copy()
    far[~where] = 1.0 - t[~where]  # what lies outside the marked pixels must not count
    ref = peak_signal_noise_ratio(t[where], p[where], data_range=1.0)
    assert psnr_where(far, t, where) == pytest.approx(ref, abs=1e-9)
    assert psnr_where(far, t, where.astype(float)) == pytest.approx(ref, abs=1e-9)  # a 0/1 mask reads the same
    assert psnr_where(p, t, np.ones(p.shape[:2])) == pytest.approx(psnr(p, t), abs=1e-9)
    assert psnr_where(p, t, np.zeros(p.shape[:2])) is None  # nothing marked, nothing to score
    with pytest.raises(ValueError, match="where: shape"):
        psnr_where(p, t, where[:, :-1])


def test_psnr_identical_is_capped_finite() -> None:
    a = np.random.default_rng(2).random((5, 5, 3))
    assert psnr(a, a) == metrics.PSNR_CAP_DB


def test_ssim_identical_is_one() -> None:
    a = np.random.default_rng(3).random((20, 30, 3))
    assert ssim_3dgs(a, a) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ssim_interior_matches_skimage(seed: int) -> None:
    p, t = _pair(seed)
    smap = ssim_map_3dgs(p, t)
    for c in range(3):
        ref = structural_similarity(p[..., c], t[..., c], gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False, data_range=1.0)
        assert smap[5:-5, 5:-5, c].mean() == pytest.approx(ref, abs=1e-10)
    # the full-map mean (3DGS) differs from the interior one on a small image
    assert abs(ssim_3dgs(p, t) - smap[5:-5, 5:-5].mean()) > 1e-4


def test_ssim_matches_torch_conv2d_zero_padding() -> None:
    """The 3DGS recipe written directly with grouped conv2d, padding=5 (zeros)."""
    p, t = _pair(4)
    x = np.arange(11) - 5
    g = np.exp(-(x**2) / (2 * 1.5**2))
    g /= g.sum()
    w = torch.from_numpy(np.outer(g, g))[None, None].repeat(3, 1, 1, 1)
    a = torch.from_numpy(p.transpose(2, 0, 1))[None]
    b = torch.from_numpy(t.transpose(2, 0, 1))[None]

    def blur(z: torch.Tensor) -> torch.Tensor:
        return F.conv2d(z, w, padding=5, groups=3)

    mu1, mu2 = blur(a), blur(b)
    s11 = blur(a * a) - mu1**2
    s22 = blur(b * b) - mu2**2
    s12 = blur(a * b) - mu1 * mu2
    c1, c2 = 0.01**2, 0.03**2
    ref = ((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1**2 + mu2**2 + c1) * (s11 + s22 + c2))
    assert ssim_3dgs(p, t) == pytest.approx(float(ref.mean()), abs=1e-10)


def test_shifted_image_scores_lower() -> None:
    _, t = _pair(5)
    shifted = np.roll(t, 3, axis=1)
    assert psnr(shifted, t) < 40.0
    assert ssim_3dgs(shifted, t) < 0.99
    assert ssim_3dgs(np.roll(t, 1, axis=1), t) > ssim_3dgs(shifted, t)


def test_grayscale_and_bad_input() -> None:
    p, t = _pair(6, (16, 16))
    assert 0.0 < ssim_3dgs(p, t) < 1.0
    with pytest.raises(ValueError, match="target"):
        psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    bad = np.zeros((4, 4, 3))
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="pred"):
        ssim_3dgs(bad, np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match="max_val"):
        psnr(bad, bad, max_val=0.0)


def test_depth_errors_closed_form() -> None:
    gt = np.array([[1.0, 2.0], [4.0, 0.0]])
    pred = np.array([[1.1, 1.8], [4.0, 7.0]])  # last pixel is sky: ignored
    e = depth_errors(pred, gt)
    assert e["absrel"] == pytest.approx((0.1 / 1 + 0.2 / 2 + 0) / 3)
    assert e["rmse"] == pytest.approx(math.sqrt((0.01 + 0.04) / 3))
    with pytest.raises(ValueError, match="gt"):
        depth_errors(pred, np.zeros((2, 2)))


def test_mask_iou() -> None:
    a = np.zeros((4, 4), np.uint8)
    b = np.zeros((4, 4), np.uint8)
    assert mask_iou(a, b) is None
    a[:2] = 255
    b[1:3] = 255
    assert mask_iou(a, b) == pytest.approx(4 / 12)
    assert mask_iou(a.astype(bool), a) == 1.0


def _random_alex_files(tmp_path, seed: int = 0) -> tuple[str, str]:
    g = torch.Generator().manual_seed(seed)
    sd = {}
    for i, (cin, cout, k) in {0: (3, 64, 11), 3: (64, 192, 5), 6: (192, 384, 3),
                              8: (384, 256, 3), 10: (256, 256, 3)}.items():
        sd[f"features.{i}.weight"] = torch.randn(cout, cin, k, k, generator=g) * (2.0 / (cin * k * k)) ** 0.5
        sd[f"features.{i}.bias"] = torch.zeros(cout)
    sd["classifier.1.weight"] = torch.zeros(4, 4)  # extra keys, as in torchvision's file, are ignored
    heads = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1, generator=g)
             for k, c in enumerate((64, 192, 384, 256, 256))}
    bb, hd = tmp_path / "alexnet-owt-7be5be79.pth", tmp_path / "alex_heads.pth"
    torch.save(sd, bb)
    torch.save(heads, hd)
    return str(bb), str(hd)


def test_lpips_network_path_with_local_weights(tmp_path) -> None:
    bb, hd = _random_alex_files(tmp_path)
    scorer, status = load_lpips(bb, heads_path=hd)
    assert scorer is not None and status.startswith("ok: alex")
    p, t = _pair(7, (64, 64, 3))
    assert scorer(t, t) == pytest.approx(0.0, abs=1e-7)
    d1, d2 = scorer(p, t), scorer(t, p)
    assert d1 > 1e-4
    assert d1 == pytest.approx(d2, rel=1e-5)
    assert scorer(np.roll(t, 8, axis=0), t) > scorer(np.roll(t, 1, axis=0), t)


def test_lpips_folder_and_torch_home_lookup(tmp_path, monkeypatch) -> None:
    ckpt = tmp_path / "hub" / "checkpoints"
    ckpt.mkdir(parents=True)
    bb, hd = _random_alex_files(ckpt)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    scorer, status = load_lpips(heads_path=hd)
    assert scorer is not None and str(ckpt) in status


def test_lpips_skipped_without_weights(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setenv("HOME", str(tmp_path))
    scorer, status = load_lpips(str(tmp_path / "nowhere.pth"))
    assert scorer is None and status.startswith("skipped: no weights")
    with pytest.raises(ValueError, match="net"):
        load_lpips(net="squeeze")


def test_lpips_rejects_wrong_state_dict(tmp_path) -> None:
    bb, hd = _random_alex_files(tmp_path)
    torch.save({"features.0.weight": torch.zeros(8, 3, 11, 11), "features.0.bias": torch.zeros(8)}, bb)
    with pytest.raises(ValueError, match="weights_path"):
        load_lpips(bb, heads_path=hd)


def _random_vgg_files(tmp_path, seed: int = 1) -> tuple[str, str]:
    g = torch.Generator().manual_seed(seed)
    sd, idx, cin = {}, 0, 3
    for block in ((64, 64), (128, 128), (256, 256, 256), (512, 512, 512), (512, 512, 512)):
        for cout in block:
            sd[f"features.{idx}.weight"] = torch.randn(cout, cin, 3, 3, generator=g) * (2.0 / (cin * 9)) ** 0.5
            sd[f"features.{idx}.bias"] = torch.zeros(cout)
            cin, idx = cout, idx + 2
        idx += 1
    heads = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1, generator=g)
             for k, c in enumerate((64, 128, 256, 512, 512))}
    bb, hd = tmp_path / "vgg16-397923af.pth", tmp_path / "vgg_heads.pth"
    torch.save(sd, bb)
    torch.save(heads, hd)
    return str(bb), str(hd)


def _reference_lpips_alex(bb: str, hd: str, pred: np.ndarray, target: np.ndarray) -> float:
    """LPIPS from its definition with torch.nn layers (torchvision's AlexNet layout), as a second
    implementation: unit-normalise each tapped ReLU's channels, square the difference, weight the
    channels with the linear head, average over space, sum over the five taps."""
    sd, heads = torch.load(bb, weights_only=True), torch.load(hd, weights_only=True)
    layers = [torch.nn.Conv2d(3, 64, 11, 4, 2), torch.nn.ReLU(), torch.nn.MaxPool2d(3, 2),
              torch.nn.Conv2d(64, 192, 5, 1, 2), torch.nn.ReLU(), torch.nn.MaxPool2d(3, 2),
              torch.nn.Conv2d(192, 384, 3, 1, 1), torch.nn.ReLU(), torch.nn.Conv2d(384, 256, 3, 1, 1),
              torch.nn.ReLU(), torch.nn.Conv2d(256, 256, 3, 1, 1), torch.nn.ReLU()]
    net = torch.nn.Sequential(*layers).double()
    net.load_state_dict({k.removeprefix("features."): v.double() for k, v in sd.items() if k.startswith("features.")})
    shift = torch.tensor([-0.030, -0.088, -0.188], dtype=torch.float64).view(1, 3, 1, 1)
    scale = torch.tensor([0.458, 0.448, 0.450], dtype=torch.float64).view(1, 3, 1, 1)
    total = 0.0
    with torch.no_grad():
        x = torch.from_numpy(np.stack([pred, target]).transpose(0, 3, 1, 2).copy()).double()
        x = (x * 2 - 1 - shift) / scale
        k = 0
        for i, layer in enumerate(net):
            x = layer(x)
            if i in (1, 4, 7, 9, 11):
                f = x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
                w = heads[f"lin{k}.model.1.weight"].double()
                total += float(((f[0:1] - f[1:2]) ** 2 * w.view(1, -1, 1, 1)).sum(1).mean())
                k += 1
    return total


def test_lpips_matches_a_layer_by_layer_reference(tmp_path) -> None:
    bb, hd = _random_alex_files(tmp_path)
    scorer, _ = load_lpips(bb, heads_path=hd)
    p, t = _pair(3, (50, 70, 3))
    assert scorer(p, t) == pytest.approx(_reference_lpips_alex(bb, hd, p, t), rel=1e-4)


def test_lpips_vgg_and_odd_sizes_with_random_weights(tmp_path) -> None:
    """VGG beside AlexNet, at sizes no stride divides; identical images score 0."""
    bb, hd = _random_vgg_files(tmp_path)
    scorer, status = load_lpips(bb, net="vgg", heads_path=hd)
    assert scorer is not None and status.startswith("ok: vgg")
    p, t = _pair(5, (37, 53, 3))
    assert scorer(t, t) == pytest.approx(0.0, abs=1e-7)
    assert np.isfinite(scorer(p, t)) and scorer(p, t) > 1e-4


def test_lpips_mismatched_or_too_small_images_are_clear_errors(tmp_path) -> None:
    """The harness once scored training-resolution renders against full-resolution ground truth
    and crashed before any table; now sizes must match, and a too-small view says so."""
    bb, hd = _random_alex_files(tmp_path)
    scorer, _ = load_lpips(bb, heads_path=hd)
    render, truth = _pair(2, (48, 64, 3))[0], _pair(2, (96, 128, 3))[1]
    with pytest.raises(ValueError, match=r"target: shape \(96, 128, 3\) does not match pred shape \(48, 64, 3\)"):
        scorer(render, truth)
    tiny = _pair(4, (16, 16, 3))
    with pytest.raises(ValueError, match="16x16 px is too small for LPIPS-alex"):
        scorer(*tiny)
