#!/usr/bin/env bash
# Copies the light record of finished train-and-evaluate runs (config.json, metrics.json,
# train_log.csv) into data/candidates/NAME/, so benchmarks/full_candidates.py can rebuild its
# tables on any clone after the run folders (and their checkpoints) are gone.
#   bash scripts/keep_runs.sh runs/chair-est-seed0 runs/chair-rgb-seed0 ...
set -euo pipefail
cd "$(dirname "$0")/.."
for run in "$@"; do
  run="${run%/}"
  if ! grep -q '"status": "ok"' "$run/metrics.json" 2>/dev/null; then
    echo "keep_runs: $run/metrics.json: status is not ok (not a finished run); skipped" >&2
    continue
  fi
  dest="data/candidates/$(basename "$run")"
  mkdir -p "$dest.partial"
  cp "$run/config.json" "$run/metrics.json" "$run/train_log.csv" "$dest.partial/"
  rm -rf "$dest"
  mv "$dest.partial" "$dest"
  echo "kept $run -> $dest"
done
