"""``python -m benchmarks.gpu_check.warm_cpu_kernel``: compile (or load from its cache) the compiled
CPU rasterizer by rendering one Gaussian with it, so the parity tests do not pay for the build."""
from __future__ import annotations

import time

import torch

from smokeseer.raster import rasterize

if __name__ == "__main__":
    start = time.perf_counter()
    eye = torch.eye(4)
    eye[2, 3] = 3.0
    k = torch.tensor([[40.0, 0, 16], [0, 40, 16], [0, 0, 1]])
    out = rasterize(torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), 0.2), torch.tensor([0.5]),
                    torch.ones(1, 3), eye[None], k[None], 32, 32, backend="cpu")
    assert float(out.alphas.max()) > 0.4
    print(f"compiled CPU rasterizer ready in {time.perf_counter() - start:.1f} s")
