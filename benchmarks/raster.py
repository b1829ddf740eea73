"""Rasterizer benchmark: forward + backward of the compiled CPU backend against the torch backend.

For each (N Gaussians, image side) the two backends run alternately in one process, each best of
``--repeats`` after a warm-up, with the load average recorded, so a busy shared machine slows
both alike. Peak memory is measured separately, one fresh subprocess per (backend, size), as
ru_maxrss minus the resident size just before rendering.

The "arithmetic floor" estimates this machine's limit per blended pair: the time torch's
vectorised kernels take for the unavoidable per-pair arithmetic (two exps, one per pass, plus the
~30 multiply-adds of the alpha, blend and gradient terms) on a cache-resident array, per element. A kernel below it would need to skip work, not to do it faster.

    python benchmarks/raster.py             # 20k/128^2, 100k/256^2, 300k/512^2 (cpu only) + memory
    python benchmarks/raster.py --quick     # small sizes, well under a minute
Writes benchmarks/results/raster.csv and raster.png.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from contracts.atomic import write_dataclass_csv  # noqa: E402

BACKENDS = ("cpu", "torch")
FLOOR_MULADDS = 30  # per-pair multiply-adds besides the exps (alpha, blend, gradient terms)


@dataclass
class Timing:
    n: int
    res: int
    cpu_s: float  # forward + backward, best of repeats
    torch_s: float
    speedup: float
    cpu_forward_s: float
    blended_pairs: int
    cpu_ns_per_pair: float
    floor_ns_per_pair: float  # arithmetic floor (see module docstring)
    threads: int
    load_avg_1min: float


@dataclass
class Memory:
    backend: str
    n: int
    res: int
    peak_mb: float
    blended_pairs: int


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


def forward_backward(backend: str, params, viewmats, ks, weights, res: int) -> tuple[float, float, int]:
    """(forward seconds, forward + backward seconds, blended pairs) of one training-like step."""
    from smokeseer.raster import rasterize

    for p in params:
        p.grad = None
    t0 = time.perf_counter()
    out = rasterize(*params, viewmats, ks, res, res, backend=backend)
    t1 = time.perf_counter()
    (torch.cat([out.colors, out.alphas, out.depths], -1) * weights).sum().backward()
    return t1 - t0, time.perf_counter() - t0, out.n_pairs


def arithmetic_floor(pairs: int, repeats: int = 20, chunk: int = 1 << 14) -> float:
    """Seconds torch's vectorised kernels need for the per-pair arithmetic of ``pairs`` pairs,
    timed on a cache-resident chunk (so it measures arithmetic, not memory) and scaled."""
    x = torch.rand(chunk)  # below torch's parallel grain: one core's vector units
    y = torch.empty_like(x)
    best = math.inf
    for _ in range(repeats + 1):  # the first pass warms up and is never the best
        t0 = time.perf_counter()
        for _ in range(2):
            torch.exp(x, out=y)
        for _ in range(FLOOR_MULADDS // 2):
            torch.addcmul(x, y, y, out=y)
        best = min(best, time.perf_counter() - t0)
    return best * pairs / chunk


def time_pair(n: int, res: int, repeats: int, with_torch: bool) -> Timing:
    """Both backends alternately in this process; best of ``repeats`` each after one warm-up.
    Without ``with_torch`` only the cpu backend runs (the torch one would not fit in memory)."""
    params, viewmats, ks, weights = make_scene(n, res)
    backends = BACKENDS if with_torch else ("cpu",)
    best = {b: (math.inf, math.inf) for b in BACKENDS}
    pairs = {}
    for i in range(repeats + 1):
        for backend in backends:
            fwd, total, pairs[backend] = forward_backward(backend, params, viewmats, ks, weights, res)
            if i > 0:
                best[backend] = min(best[backend], (total, fwd))
    if with_torch and abs(pairs["cpu"] - pairs["torch"]) > 1e-4 * pairs["torch"]:
        raise RuntimeError(f"backends blended different pair counts: {pairs}")
    cpu_s, cpu_fwd = best["cpu"]
    torch_s = best["torch"][0]
    floor = arithmetic_floor(pairs["cpu"])
    return Timing(n, res, cpu_s, torch_s, torch_s / cpu_s, cpu_fwd, pairs["cpu"],
                  cpu_s / max(pairs["cpu"], 1) * 1e9, floor / max(pairs["cpu"], 1) * 1e9,
                  torch.get_num_threads(), os.getloadavg()[0])


def _status_mb(field: str) -> float:
    with open("/proc/self/status") as f:
        line = next(ln for ln in f if ln.startswith(field + ":"))
    return int(line.split()[1]) / 1024


def memory_worker(backend: str, n: int, res: int) -> Memory:
    """Peak resident memory of one forward + backward, measured in this (fresh) process: a tiny
    warm-up render first (one-off allocator, OpenMP and autograd set-up), then the kernel's peak
    RSS counter (VmHWM) is reset through /proc/self/clear_refs and read after the render."""
    params, viewmats, ks, weights = make_scene(200, 32)
    forward_backward(backend, params, viewmats, ks, weights, 32)
    params, viewmats, ks, weights = make_scene(n, res)
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    base = _status_mb("VmRSS")
    _, _, pairs = forward_backward(backend, params, viewmats, ks, weights, res)
    return Memory(backend, n, res, _status_mb("VmHWM") - base, pairs)


def measure_memory(backend: str, n: int, res: int, threads: int) -> Memory:
    cmd = [sys.executable, __file__, "--memory-worker", json.dumps([backend, n, res]), "--threads", str(threads)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"memory worker failed for {backend} {n} {res}:\n{proc.stderr}")
    return Memory(**json.loads(proc.stdout.strip().splitlines()[-1]))


def write_plot(path: Path, timings: list[Timing], memory: list[Memory]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    pairs = [t.blended_pairs for t in timings]
    with_torch = [t for t in timings if math.isfinite(t.torch_s)]
    axes[0].loglog([t.blended_pairs for t in with_torch], [t.torch_s for t in with_torch], "s--", label="torch backend")
    axes[0].loglog(pairs, [t.cpu_s for t in timings], "o-", label="cpu backend (compiled)")
    axes[0].loglog(pairs, [t.floor_ns_per_pair * t.blended_pairs * 1e-9 for t in timings], ":", label="arithmetic floor")
    for t in timings:
        gain = f" ({t.speedup:.0f}x)" if math.isfinite(t.speedup) else ""
        axes[0].annotate(f"{t.n // 1000}k,{t.res}²{gain}", (t.blended_pairs, t.cpu_s), fontsize=7)
    axes[0].set(xlabel="blended (Gaussian, pixel) pairs", ylabel="forward + backward [s]", title="time")
    for backend, style in (("cpu", "o-"), ("torch", "s--")):
        rows = sorted((m.blended_pairs, m.peak_mb) for m in memory if m.backend == backend)
        if rows:
            axes[1].loglog(*zip(*rows), style, label=f"{backend} backend")
    axes[1].set(xlabel="blended (Gaussian, pixel) pairs", ylabel="peak memory [MB]", title="memory")
    for ax in axes:
        ax.legend()
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    tmp = path.with_suffix(".partial.png")
    fig.savefig(tmp, dpi=120)
    tmp.replace(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small sizes for a smoke check")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per backend (best is kept)")
    parser.add_argument("--threads", type=int, default=0, help="torch (and kernel) threads; default torch's own")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--memory-worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.memory_worker:
        print(json.dumps(asdict(memory_worker(*json.loads(args.memory_worker)))))
        return
    sizes = [(2000, 64), (5000, 128)] if args.quick else [(20000, 128), (100000, 256), (300000, 512)]
    mem_sizes = sizes if args.quick else [(5000, 128), (20000, 128), (20000, 256), (100000, 256), (300000, 512)]
    # The torch backend keeps ~300 B per blended pair; 300k Gaussians at 512^2 blend ~50M pairs.
    torch_sizes = set(sizes) - {(300000, 512)}
    from smokeseer.raster.extension import load_kernel

    load_kernel()
    timings = []
    for n, res in sizes:
        t = time_pair(n, res, args.repeats, (n, res) in torch_sizes)
        timings.append(t)
        print(f"N={n:>6d} {res:>3d}^2  cpu {t.cpu_s * 1e3:8.1f} ms (forward {t.cpu_forward_s * 1e3:.1f})  "
              f"torch {t.torch_s * 1e3:8.1f} ms  speed-up {t.speedup:5.1f}x  pairs {t.blended_pairs:>9d}  "
              f"{t.cpu_ns_per_pair:5.1f} ns/pair (floor {t.floor_ns_per_pair:.1f})  threads {t.threads}  "
              f"load {t.load_avg_1min:.1f}", flush=True)
    memory = []
    for n, res in mem_sizes:
        for backend in BACKENDS if (n, res) in torch_sizes or (n, res) not in set(sizes) else ("cpu",):
            m = measure_memory(backend, n, res, torch.get_num_threads())
            memory.append(m)
            print(f"memory {backend:5s} N={n:>6d} {res:>3d}^2  peak {m.peak_mb:8.1f} MB  pairs {m.blended_pairs:>9d}  "
                  f"{m.peak_mb * 2**20 / max(m.blended_pairs, 1):6.0f} B/pair", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    write_dataclass_csv(args.out / "raster.csv", timings)
    write_dataclass_csv(args.out / "raster_memory.csv", memory)
    write_plot(args.out / "raster.png", timings, memory)
    print(f"wrote {args.out / 'raster.csv'}, raster_memory.csv and raster.png")


if __name__ == "__main__":
    main()
