#!/usr/bin/env bash
# Issue 49's density sweep, the datasets: three standard scenes at a ladder of smoke density
# scales k (opacity 1-(1-a)^k; k = 0 is the smoke-free scene with the same cameras), every k of a
# scene rendered from one Mantaflow bake, kept in BAKES. One generate-benchmark call per k writes
# OUT/kK/SCENE; each call resumes where it stopped, and a finished dataset is skipped.
#
#   bash benchmarks/density_sweep_generate.sh [OUT] [BAKES]     (defaults: data/density_sweep runs/bakes)
#
# k = 1 is not rendered again: it is the standard benchmark's dataset of the scene, linked as
# OUT/k1/SCENE. The sweep's bakes reproduce the standard datasets' simulations (their RGB frames
# come out byte for byte; docs/experiments/2026-11-29-density-sweep-k1.md), so Full and RGB-only
# at k = 1 are Table 1's runs (benchmarks/density_sweep_train.sh links them). k = 1 also provides
# the clean passes of every other k (--clean-from): they never see the smoke, so they are the same
# at every k, and they are the costliest pass; each k renders only the smoky, depth and
# smoke-alpha passes.
#
# The ladder reaches, per scene, a k where the smoky input falls to about the paper's 15 dB
# (estimated from k = 1 by benchmarks/density_ladder.py): chair and food_plate near k = 8, the
# excavator (the large scene) near k = 2-4. house, the other large scene, cannot: its smoke
# covers little of each view, and its input stays above 18 dB even at k = 64.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-data/density_sweep}
bakes=${2:-runs/bakes}
standard=data/standard
sweep=(chair food_plate excavator)
mkdir -p "$out/k1"
for s in "${sweep[@]}"; do
    ln -sfn "$(realpath --relative-to="$out/k1" "$standard/$s")" "$out/k1/$s"
done
ladder=("0:chair,food_plate,excavator" "2:chair,food_plate,excavator" "4:chair,food_plate,excavator"
        "8:chair,food_plate" "0.5:chair,food_plate,excavator")
for entry in "${ladder[@]}"; do
    k=${entry%%:*}
    echo "== $(date -u +%FT%TZ) k=$k: ${entry#*:}" >&2
    .venv/bin/generate-benchmark --profile standard --scenes "${entry#*:}" --density-scale "$k" \
        --bake-cache "$bakes" --clean-from "$out/k1" --out "$out/k$k" --quiet
done
