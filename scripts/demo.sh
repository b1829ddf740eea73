#!/usr/bin/env bash
# Installs everything, then runs the main job end to end on the embedded `demo` scene:
# generate the dataset, train SmokeSeer on it, and score the de-smoked novel views.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
. .venv/bin/activate
OUT="${OUT:-runs/demo}"
generate-scene --preset demo --out "$OUT/dataset" --force
generate-scene --validate "$OUT/dataset"
