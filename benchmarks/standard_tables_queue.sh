#!/usr/bin/env bash
# Issue 16's standard-profile runs as a work queue, one run per regenerate-tables call, for filling
# the tables over several days, stopped and restarted at will, with two of these side by side. Each call says --workers 2, as
# standard_tables.sh does, so that its one run trains on one thread (the harness gives a run
# cores/workers threads) like every other run of the tables. The queue is
# standard_tables.sh's order cut into single runs: Table 1 at seed 0, Table 2's ablations at seed
# 0 (the harness's default list for the standard profile), then Table 1 at seeds 1 and 2.
# A worker claims a step by creating its folder under CLAIMS (mkdir is atomic; the step's log
# goes there), so two workers never train the same run; cached steps cost seconds.
# After the tables come the twice-the-budget runs (Stage 3 at 6000 iterations, everything else
# as the profile; into data/tables_standard_2x) of Full and RGB-only at seed 0 on the scenes
# where Full trails RGB-only at 3000, to measure what convergence.md extrapolates.
# A worker stops before its next step once CLAIMS/STOP exists. An interrupted run resumes from its
# checkpoint when its step's claim folder is removed and a worker reaches it again. Afterwards,
# `bash benchmarks/standard_tables.sh --finished-only` writes the tables.
#
#   bash benchmarks/standard_tables_queue.sh NAME [CLAIMS]     (CLAIMS default: runs/claims)
set -euo pipefail
cd "$(dirname "$0")/.."
name=${1:?usage: standard_tables_queue.sh NAME [CLAIMS]}
claims=${2:-runs/claims}
root=data/standard
out=data/tables_standard
mkdir -p "$claims"
source benchmarks/standard_scenes.sh
mapfile -t scenes < <(standard_scenes "$root")
mapfile -t ablations < <(.venv/bin/python -c \
    "from eval.harness import default_ablations; print(*default_ablations('standard', {}), sep='\n')")
steps=()
add_table1_steps() {  # add_table1_steps SEED: every scene's three Table 1 methods at SEED
    local s m
    for s in "${scenes[@]}"; do for m in full rgb-only imgdehaze-dcp; do steps+=("$s $m $1 -"); done; done
}
add_table1_steps 0
for s in "${scenes[@]}"; do for a in "${ablations[@]}"; do steps+=("$s full 0 $a"); done; done
add_table1_steps 1
add_table1_steps 2
for s in house food_plate plant rover chair; do for m in full rgb-only; do steps+=("$s $m 0 - 2x"); done; done
for step in "${steps[@]}"; do
    if [[ -e "$claims/STOP" ]]; then echo "[$name] $(date -u +%FT%TZ) STOP found, leaving"; exit 0; fi
    read -r scene method seed ablation budget <<< "$step"
    claim="$claims/$(echo "$step" | md5sum | cut -c1-12)"
    mkdir "$claim" 2>/dev/null || continue
    if [[ $ablation == - ]]; then which=(--no-ablations); else which=(--ablations --ablation-list "$ablation"); fi
    target=(--out "$out")
    if [[ $budget == 2x ]]; then target=(--out "${out}_2x" --set stage3.iterations=6000); fi
    echo "[$name] $(date -u +%FT%TZ) start $step"
    t0=$SECONDS
    rc=0
    .venv/bin/regenerate-tables --profile standard --workers 2 --scenes "$scene" --dataset "$scene=$root/$scene" \
        --methods "$method" --seeds "$seed," "${which[@]}" "${target[@]}" > "$claim/log" 2>&1 || rc=$?
    echo "[$name] $(date -u +%FT%TZ) done $step rc=$rc $((SECONDS - t0)) s"
done
echo "[$name] $(date -u +%FT%TZ) queue empty"
