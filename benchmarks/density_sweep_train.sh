#!/usr/bin/env bash
# Issue 49's density sweep, the runs: Full and RGB-only at the standard profile, seeds 0-2, on
# every dataset benchmarks/density_sweep_generate.sh has finished. One regenerate-tables call per
# density into TABLES_kK (its runs keyed and resumed like the standard tables'; data/README.md),
# then benchmarks/density_sweep.py writes the curves. At k = 1 the datasets are the standard
# benchmark's (benchmarks/density_sweep_generate.sh), so TABLES_k1/runs/SCENE links to Table 1's
# runs of the scene: finished ones are taken as they are, and one trained here is Table 1's too.
#
#   bash benchmarks/density_sweep_train.sh [DATASETS] [TABLES] [extra regenerate-tables options]
#   (defaults: data/density_sweep data/tables_density; --finished-only trains nothing; with it,
#   --digest PREFIX tables the runs of an earlier trainer, and goes to density_sweep.py too)
set -euo pipefail
cd "$(dirname "$0")/.."
datasets=data/density_sweep
tables=data/tables_density
if [[ $# -gt 0 && $1 != --* ]]; then datasets=$1; shift; fi
if [[ $# -gt 0 && $1 != --* ]]; then tables=$1; shift; fi
digest=()
opts=("$@")
for ((i = 0; i < ${#opts[@]} - 1; i++)); do [[ ${opts[i]} == --digest ]] && digest=(--digest "${opts[i + 1]}"); done
source benchmarks/density_sweep_plan.sh
mapfile -t entries < <(sweep_datasets "$datasets")
for k in $(printf '%s\n' "${entries[@]%% *}" | uniq); do
    scenes=() args=()
    for entry in "${entries[@]}"; do
        [[ ${entry%% *} == "$k" ]] || continue
        s=${entry#* }
        scenes+=("$s")
        args+=(--dataset "$s=$datasets/$k/$s")
    done
    if [[ $k == k1 ]]; then
        mkdir -p "${tables}_k1/runs"
        for s in "${scenes[@]}"; do
            ln -sfn "$(realpath --relative-to="${tables}_k1/runs" data/tables_standard/runs/"$s")" "${tables}_k1/runs/$s"
        done
    fi
    echo "== $(date -u +%FT%TZ) $k: ${scenes[*]}" >&2
    .venv/bin/regenerate-tables --profile standard --workers 2 --scenes "$(IFS=,; echo "${scenes[*]}")" \
        "${args[@]}" --methods "$(IFS=,; echo "${sweep_methods[*]}")" \
        --seeds "$(IFS=,; echo "${sweep_seeds[*]}")" --no-ablations --out "${tables}_$k" "$@" \
        || [[ $? -eq 1 ]]  # 1: tables written, some runs failed (report.md)
done
.venv/bin/python benchmarks/density_sweep.py --datasets "$datasets" --tables "$tables" "${digest[@]}"
