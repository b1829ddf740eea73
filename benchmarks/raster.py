"""Rasterizer benchmark: forward + backward time and peak memory of the torch backend against the
dense all-pairs reference, over Gaussian count and resolution.

Each measurement runs in a fresh subprocess so its peak resident memory (ru_maxrss minus the
resident size just before rendering) belongs to that configuration alone. The dense reference
runs pixel chunks, each back-propagated into the once-projected Gaussians (memory ~ chunk x N). Its cost per pixel
does not depend on the scene (every pixel evaluates all N Gaussians), so by default the
projection is timed on its own, the compositing on an evenly spread subset of chunks, and the
latter is scaled to the full image; --full-dense times every chunk.

    python benchmarks/raster.py            # default sweep, a few minutes on 2 cores
    python benchmarks/raster.py --quick    # small sweep, well under a minute
Writes benchmarks/results/raster.csv and raster.png.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import resource
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

DENSE_CHUNK = 256  # pixels per dense chunk


@dataclass
class Config:
    kind: str  # "torch" or "dense"
    n: int
    res: int
    repeats: int = 5
    dense_pixels: int = 0  # 0: all pixels; else at least this many, spread over the image
    threads: int = 0


@dataclass
class Result:
    kind: str
    n: int
    res: int
    seconds: float  # forward + backward, best of repeats after a warm-up (dense: one run, scaled)
    peak_mb: float
    blended_pairs: int
    pixels_timed: int
    threads: int
    load_avg_1min: float  # machine load while measuring (2-core machines shared with other jobs)


def make_scene(n: int, res: int, seed: int = 0) -> tuple[list[torch.Tensor], torch.Tensor, torch.Tensor, torch.Tensor]:
    """Gaussians filling a 53-degree frustum at depths 2-6, with trainer-like sizes (~2-8 px at 128^2)."""
    g = torch.Generator().manual_seed(seed)
    z = torch.rand(n, generator=g) * 4 + 2
    xy = (torch.rand(n, 2, generator=g) - 0.5) * z[:, None] * 1.1
    means = torch.cat([xy, z[:, None]], dim=1)
    quats = torch.randn(n, 4, generator=g)
    scales = torch.exp(torch.randn(n, 3, generator=g) * 0.5 + math.log(0.02))
    opac = torch.rand(n, generator=g) * 0.8 + 0.1
    colors = torch.rand(n, 3, generator=g)
    params = [t.requires_grad_(True) for t in (means, quats, scales, opac, colors)]
    viewmats = torch.eye(4)[None]
    ks = torch.tensor([[[float(res), 0, res / 2], [0, float(res), res / 2], [0, 0, 1]]])
    weights = torch.randn(1, res, res, 5, generator=g)
    return params, viewmats, ks, weights


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def run_worker(cfg: Config) -> Result:
    """Measure one configuration in this process."""
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    from smokeseer.raster import rasterize
    from tests.raster_reference import dense_loss_backward

    params, viewmats, ks, weights = make_scene(cfg.n, cfg.res)
    base = _rss_mb()
    pairs, pixels = 0, cfg.res * cfg.res
    times = []
    if cfg.kind == "torch":
        for _ in range(cfg.repeats + 1):
            for p in params:
                p.grad = None
            t0 = time.perf_counter()
            out = rasterize(*params, viewmats, ks, cfg.res, cfg.res)
            (torch.cat([out.colors, out.alphas, out.depths], -1) * weights).sum().backward()
            times.append(time.perf_counter() - t0)
            pairs = out.n_pairs
            del out
        seconds = min(times[1:])  # best of the repeats: the machine is shared, noise only adds time
    else:
        n_chunks = math.ceil(pixels / DENSE_CHUNK)
        want = n_chunks if not cfg.dense_pixels else min(n_chunks, math.ceil(cfg.dense_pixels / DENSE_CHUNK))
        picks = sorted({round(i * (n_chunks - 1) / max(want - 1, 1)) for i in range(want)})
        elapsed = []
        for subset in ([], picks):  # fixed cost (projection), then fixed cost + the timed chunks
            t0 = time.perf_counter()
            dense_loss_backward(*params, viewmats, ks, cfg.res, cfg.res, weights, pixel_chunk=DENSE_CHUNK, chunks=subset)
            elapsed.append(time.perf_counter() - t0)
        timed = sum(min(DENSE_CHUNK, pixels - i * DENSE_CHUNK) for i in picks)
        seconds = elapsed[0] + (elapsed[1] - elapsed[0]) * pixels / timed
        pixels = timed
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - base
    return Result(cfg.kind, cfg.n, cfg.res, seconds, peak, pairs, pixels, torch.get_num_threads(), os.getloadavg()[0])


def measure(cfg: Config) -> Result:
    """Run one configuration in a fresh interpreter and parse its result."""
    proc = subprocess.run([sys.executable, __file__, "--worker", json.dumps(asdict(cfg))],
                          capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"worker failed for {cfg}:\n{proc.stderr}")
    return Result(**json.loads(proc.stdout.strip().splitlines()[-1]))


def plan(quick: bool, full_dense: bool) -> list[Config]:
    dense_px = 0 if full_dense else 2048
    if quick:
        counts, res_sweep, dense = [1000, 5000], [64, 128], {(1000, 64), (5000, 64), (5000, 128)}
    else:
        counts, res_sweep = [1000, 5000, 20000, 100000], [64, 128, 256]
        dense = {(1000, 128), (5000, 128), (20000, 128), (20000, 64)}
    fixed_n = counts[-1] if quick else 20000
    grid = {(n, 128 if not quick else 64) for n in counts} | {(fixed_n, r) for r in res_sweep}
    cfgs = [Config("torch", n, r) for n, r in sorted(grid)]
    cfgs += [Config("dense", n, r, repeats=1, dense_pixels=dense_px) for n, r in sorted(dense)]
    return cfgs


def write_outputs(results: list[Result], out_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    dense = {(r.n, r.res): r for r in results if r.kind == "dense"}
    rows = []
    for r in results:
        d = dense.get((r.n, r.res)) if r.kind == "torch" else None
        rows.append({**asdict(r), "speedup_vs_dense": f"{d.seconds / r.seconds:.1f}" if d else "",
                     "dense_to_torch_memory": f"{d.peak_mb / max(r.peak_mb, 1e-3):.2f}" if d else ""})
    with open(out_dir / "raster.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    res_main = max({r.res for r in results}, key=lambda v: sum(x.res == v for x in results))
    n_main = max({r.n for r in results}, key=lambda v: sum(x.n == v for x in results))
    for kind, style in (("torch", "o-"), ("dense", "s--")):
        by_n = sorted((r.n, r.seconds) for r in results if r.kind == kind and r.res == res_main)
        by_res = sorted((r.res, r.seconds) for r in results if r.kind == kind and r.n == n_main)
        if by_n:
            axes[0].loglog(*zip(*by_n), style, label=kind)
        if by_res:
            axes[1].loglog(*zip(*by_res), style, label=kind)
    axes[0].set(xlabel="Gaussians", ylabel="forward + backward [s]", title=f"{res_main}x{res_main}")
    axes[1].set(xlabel="image side [px]", ylabel="forward + backward [s]", title=f"N = {n_main}")
    fast = [r for r in results if r.kind == "torch"]
    axes[2].loglog([r.blended_pairs for r in fast], [r.peak_mb for r in fast], "o")
    for r in fast:
        axes[2].annotate(f"{r.n // 1000}k,{r.res}", (r.blended_pairs, r.peak_mb), fontsize=7)
    axes[2].set(xlabel="blended (Gaussian, pixel) pairs", ylabel="peak memory [MB]", title="torch backend memory")
    for ax in axes[:2]:
        ax.legend()
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out_dir / "raster.png", dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small sweep for a smoke check")
    parser.add_argument("--full-dense", action="store_true", help="time the dense reference on every pixel")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's own)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(asdict(run_worker(Config(**json.loads(args.worker))))))
        return
    results = []
    for cfg in plan(args.quick, args.full_dense):
        cfg.threads = args.threads
        r = measure(cfg)
        results.append(r)
        print(f"{r.kind:6s} N={r.n:>6d} {r.res:>4d}^2  {r.seconds:8.3f} s  peak {r.peak_mb:8.1f} MB  "
              f"pairs {r.blended_pairs:>9d}  threads {r.threads}  load {r.load_avg_1min:.1f}", flush=True)
    dense = {(r.n, r.res): r for r in results if r.kind == "dense"}
    for r in results:
        if r.kind == "torch" and (r.n, r.res) in dense:
            d = dense[(r.n, r.res)]
            print(f"N={r.n:>6d} {r.res}^2: torch is {d.seconds / r.seconds:7.1f}x faster than dense; "
                  f"memory {r.peak_mb:.1f} MB vs dense (chunked, {DENSE_CHUNK} px) {d.peak_mb:.1f} MB; "
                  f"dense would hold {r.n * r.res * r.res / 1e6:.0f}M pairs unchunked")
    write_outputs(results, args.out)
    print(f"wrote {args.out / 'raster.csv'} and {args.out / 'raster.png'}")


if __name__ == "__main__":
    main()
