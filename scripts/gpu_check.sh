#!/usr/bin/env bash
# The GPU check (docs/scale-out.md): on a Linux node with an NVIDIA GPU, torch with CUDA, nvcc and
# ninja, and no internet. WHEELS is the folder `python -m benchmarks.gpu_check.make_wheels` made.
# Usage: scripts/gpu_check.sh WHEELS [OUT] [--budget SECONDS ...]
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 1 ]; then
  echo "usage: scripts/gpu_check.sh WHEELS [OUT] [options of python -m benchmarks.gpu_check.run]" >&2
  exit 2
fi
WHEELS="$1"
OUT="${2:-runs/gpu_check}"
shift $(( $# < 2 ? $# : 2 ))
PY="${PYTHON:-python3}"
if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then
  echo "gpu_check: error: $PY is Python $("$PY" -c 'import platform; print(platform.python_version())'); the project needs 3.11 or later" >&2
  exit 2
fi
exec "$PY" -m benchmarks.gpu_check.run --wheels "$WHEELS" --out "$OUT" "$@"
