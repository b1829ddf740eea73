#!/usr/bin/env bash
# Issue 49's density sweep, the datasets: three standard scenes at a ladder of smoke density
# scales k (opacity 1-(1-a)^k; k = 0 is the smoke-free scene with the same cameras), every k of a
# scene rendered from one Mantaflow bake, kept in BAKES. One generate-benchmark call per k writes
# OUT/kK/SCENE; each call resumes where it stopped, and a finished dataset is skipped.
#
#   bash benchmarks/density_sweep_generate.sh [OUT] [BAKES]     (defaults: data/density_sweep runs/bakes)
#
# The ladder reaches, per scene, a k where the smoky input falls to about the paper's 15 dB:
# chair and food_plate get there near k = 8; house's smoke covers little of each view (mean
# optical depth 0.03 at k = 1), so its ladder runs to k = 64 (benchmarks/results/density_sweep/).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-data/density_sweep}
bakes=${2:-runs/bakes}
ladder=("0:chair,food_plate,house" "1:chair,food_plate,house" "4:chair,food_plate,house"
        "0.5:chair,food_plate" "2:chair,food_plate" "8:chair,food_plate" "16:house" "64:house")
for entry in "${ladder[@]}"; do
    k=${entry%%:*}
    echo "== $(date -u +%FT%TZ) k=$k: ${entry#*:}" >&2
    .venv/bin/generate-benchmark --profile standard --scenes "${entry#*:}" --density-scale "$k" \
        --bake-cache "$bakes" --out "$out/k$k" --quiet
done
