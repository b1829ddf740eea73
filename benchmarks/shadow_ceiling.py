"""Usage: python benchmarks/shadow_ceiling.py OUT_DIR (from shadow_pass.py).

PSNR against the clean truth of the smoke-lit clean render (the best a line-of-sight
de-smoker can reach) and of the smoky input, per test frame, from shadow_pass.py's output."""
import sys
from pathlib import Path

import numpy as np

from contracts.imageio import image01, read_png
from contracts.metrics import psnr

out = Path(sys.argv[1])
rows = []
for f in sorted((out / "smoky").glob("*.png")):
    clean, lit, smoky = (image01(read_png(out / k / f.name))[..., :3] for k in ("clean", "lit_through_smoke", "smoky"))
    rows.append((psnr(lit, clean), psnr(smoky, clean), *(lit - clean).mean((0, 1))))
    print(f.stem, "lit-through vs clean %.2f dB  smoky vs clean %.2f dB  brightness change %s" % (
        rows[-1][0], rows[-1][1], np.round(rows[-1][2:], 3)))
r = np.array(rows)
print("MEAN lit-through vs clean %.2f dB  smoky vs clean %.2f dB  brightness change %s  (%d frames)" % (
    r[:, 0].mean(), r[:, 1].mean(), np.round(r[:, 2:].mean(0), 3), len(r)))
