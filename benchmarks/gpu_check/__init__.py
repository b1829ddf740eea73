"""The GPU check: install from a wheel folder without internet, build gsplat's CUDA code, test its
parity with the compiled CPU rasterizer, train one standard dataset, report (docs/scale-out.md)."""
