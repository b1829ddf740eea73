"""The per-iteration work outside the rasterizer, before and after issue 13's last part, timed
side by side in one process (alternating, best of several repeats, thread CPU time) at the demo's quick-profile
sizes: SSIM forward + backward, the NaN guard, the state snapshot and the Adam step.

    OMP_NUM_THREADS=1 python benchmarks/iteration_parts.py [--gaussians 12000] [--out benchmarks/results]

The "before" columns are the former implementations, kept here as references: a dense 11x11
SSIM blur per map, one ``isfinite().all()`` and host sync per tensor, a recursive snapshot that
detaches and clones leaf by leaf, and the per-op (non-fused) Adam.
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from smokeseer.train.loop import detached_copy, guard  # noqa: E402
from smokeseer.train.losses import ssim  # noqa: E402
from smokeseer.train.util import check_finite  # noqa: E402

# 3DGS layout of one Gaussian set: means, log-scales, quaternions, opacity logit, SH DC and rest.
SET_SHAPES = {"means": (3,), "scales": (3,), "quats": (4,), "opacity": (1,), "sh0": (1, 3), "shN": (15, 3)}


def ssim_dense(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The former SSIM: one 11x11 grouped convolution per map (same convention)."""
    c = pred.shape[-1]
    x, y = pred.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None]
    t = torch.arange(11, dtype=pred.dtype) - 5
    g = torch.exp(-(t ** 2) / (2 * 1.5 ** 2))
    w = torch.outer(g / g.sum(), g / g.sum()).expand(c, 1, 11, 11).contiguous()

    def blur(z: torch.Tensor) -> torch.Tensor:
        return F.conv2d(z, w, padding=5, groups=c)

    mx, my = blur(x), blur(y)
    sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    num = (2 * mx * my + 0.01 ** 2) * (2 * sxy + 0.03 ** 2)
    den = (mx * mx + my * my + 0.01 ** 2) * (sxx + syy + 0.03 ** 2)
    return (num / den).mean()


def snapshot_recursive(obj: Any) -> Any:
    """The former snapshot: detach and clone every leaf, recursing into every value."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().clone()
    if isinstance(obj, dict):
        return {k: snapshot_recursive(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(snapshot_recursive(v) for v in obj)
    return obj


def best_of(fn: Callable[[], Any], reps: int, inner: int) -> float:
    """Best mean CPU time of the calling thread (one torch thread): on this shared machine wall
    time mostly measures the wait for a core."""
    best = float("inf")
    for _ in range(reps):
        t = time.thread_time()
        for _ in range(inner):
            fn()
        best = min(best, (time.thread_time() - t) / inner)
    return best


def gaussian_set(n: int, fused: bool) -> tuple[dict[str, torch.nn.Parameter], torch.optim.Adam]:
    params = {k: torch.nn.Parameter(torch.randn(n, *s)) for k, s in SET_SHAPES.items()}
    opt = torch.optim.Adam([{"params": [p], "lr": 1e-3, "name": k} for k, p in params.items()],
                           lr=0.0, eps=1e-15, fused=fused)
    for p in params.values():
        p.grad = torch.randn_like(p)
    opt.step()
    return params, opt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gaussians", type=int, default=12000, help="surface + smoke Gaussians (demo Stage 3: ~12.6k)")
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = ap.parse_args()
    torch.manual_seed(0)
    n_surface, n_smoke = int(args.gaussians * 0.8), args.gaussians - int(args.gaussians * 0.8)

    img = torch.rand(48, 64, 3, requires_grad=True)
    ref = torch.rand(48, 64, 3)
    ssim_pair = (lambda: ssim_dense(img, ref).backward(), lambda: ssim(img, ref).backward())

    sets = {name: gaussian_set(n, fused=True) for name, n in (("surface", n_surface), ("smoke", n_smoke))}
    named = [(f"{s}.{k}.grad", p.grad) for s, (ps, _) in sets.items() for k, p in ps.items()]
    named += [(f"loss.{t}", torch.tensor(0.5)) for t in ("render_rgb", "render_thermal", "mask", "depth")]
    guard_pair = (lambda: check_finite(3, 1, named), lambda: guard(3, 1, named))

    def state() -> dict[str, Any]:
        return {**{s: {k: p.detach() for k, p in ps.items()} for s, (ps, _) in sets.items()},
                **{f"{s}_optimizer": opt.state_dict() for s, (_, opt) in sets.items()}}
    snap_pair = (lambda: snapshot_recursive(state()), lambda: detached_copy(state()))

    per_op = {name: gaussian_set(n, fused=False) for name, n in (("surface", n_surface), ("smoke", n_smoke))}
    adam_pair = (lambda: [opt.step() for _, opt in per_op.values()], lambda: [opt.step() for _, opt in sets.values()])

    rows = []
    load = os.getloadavg()[0]
    for part, (before, after) in (("ssim 64x48x3 fwd+bwd", ssim_pair), ("nan guard (grads + losses)", guard_pair),
                                  ("state snapshot", snap_pair), ("adam step (2 sets)", adam_pair)):
        b = a = float("inf")
        for _ in range(2):  # alternate the two sides so load drifts hit both
            b = min(b, best_of(before, args.reps, 20))
            a = min(a, best_of(after, args.reps, 20))
        rows.append((part, b * 1e3, a * 1e3, b / a))
        print(f"{part:28s} before {b * 1e3:7.3f} ms  after {a * 1e3:7.3f} ms  {b / a:5.2f}x")
    print(f"gaussians {args.gaussians}, threads {torch.get_num_threads()}, load {load:.1f}")
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "iteration_parts.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["part", "before_ms", "after_ms", "speedup", "gaussians", "threads", "load_avg_1min"])
        for part, b, a, r in rows:
            w.writerow([part, f"{b:.4f}", f"{a:.4f}", f"{r:.3f}", args.gaussians, torch.get_num_threads(), f"{load:.2f}"])


if __name__ == "__main__":
    main()
