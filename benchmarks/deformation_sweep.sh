#!/usr/bin/env bash
# Validation PSNR against Stage-3 cost of the smoke's motion settings, on the ten standard scenes at
# seed 0 (issue 105). For the standard Full (the baseline, labelled estimated-floor) and each
# SETTINGS given (space-separated deform.* KEY=VALUE words, labelled by themselves): one
# train-and-evaluate run per scene (one thread; resumed where it stopped), its runs added to the
# candidate table `deformation_sweep`, and its Stage-3 iteration profiled on the run's own
# checkpoints and counts; then benchmarks/deformation_tradeoff.py draws the curve. Profile quietly
# (nothing else running): the costs are the curve's x axis.
#
#   bash benchmarks/deformation_sweep.sh OUT "deform.kind=planes" "deform.kind=planes deform.planes_levels=1" ...
#   (OUT: the runs' folder, e.g. data/deformation_sweep)
set -euo pipefail
cd "$(dirname "$0")/.."
[[ $# -ge 1 ]] || { echo "usage: bash benchmarks/deformation_sweep.sh OUT [SETTINGS ...]" >&2; exit 2; }
out=$1; shift
source benchmarks/standard_scenes.sh
mapfile -t scenes < <(standard_scenes data/standard)
for settings in "" "$@"; do
    label=${settings:-estimated-floor}
    slug=${settings:-standard}; slug=${slug//[^A-Za-z0-9_.]/_}
    sets=() runs=()
    for word in $settings; do sets+=(--set "$word"); done
    for s in "${scenes[@]}"; do
        run=$out/$slug/$s
        echo "== $(date -u +%FT%TZ) $label: $s" >&2
        .venv/bin/train-and-evaluate "data/standard/$s" --profile standard --seed 0 --threads 1 --no-progress \
            "${sets[@]}" --out "$run"
        runs+=("$label=$run")
        .venv/bin/python benchmarks/iteration_profile.py --scenes "$s" --modes full --counts-from "$run" \
            --checkpoints "$run/checkpoints" "${sets[@]}"
    done
    .venv/bin/python benchmarks/full_candidates.py deformation_sweep --add "${runs[@]}"
done
.venv/bin/python benchmarks/deformation_tradeoff.py --table deformation_sweep
