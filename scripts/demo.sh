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
train-and-evaluate "$OUT/dataset" --mode full --out "$OUT/train" --profile quick
python -c "import json, sys; m = json.load(open(sys.argv[1]))['metrics']; print('de-smoked test views vs clean ground truth: PSNR %.2f dB (smoky input %.2f dB), SSIM %.3f, LPIPS %s' % (m['psnr'], m['psnr_input'], m['ssim'], m['lpips'] if m['lpips'] is not None else m['lpips_status']))" "$OUT/train/metrics.json"
