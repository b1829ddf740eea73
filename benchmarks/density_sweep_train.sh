#!/usr/bin/env bash
# Issue 49's density sweep, the runs: Full and RGB-only at the standard profile, seeds 0-2, on
# every dataset benchmarks/density_sweep_generate.sh has finished. One regenerate-tables call per
# density into TABLES_kK (its runs keyed and resumed like the standard tables'; data/README.md),
# then benchmarks/density_sweep.py writes the curves.
#
#   bash benchmarks/density_sweep_train.sh [DATASETS] [TABLES] [extra regenerate-tables options]
#   (defaults: data/density_sweep data/tables_density; --finished-only trains nothing)
set -euo pipefail
cd "$(dirname "$0")/.."
datasets=data/density_sweep
tables=data/tables_density
if [[ $# -gt 0 && $1 != --* ]]; then datasets=$1; shift; fi
if [[ $# -gt 0 && $1 != --* ]]; then tables=$1; shift; fi
for folder in "$datasets"/k*/; do
    k=$(basename "$folder")
    scenes=() args=()
    for d in "$folder"*/; do
        [[ -f $d/dataset.json ]] || continue
        s=$(basename "$d")
        scenes+=("$s")
        args+=(--dataset "$s=${d%/}")
    done
    [[ ${#scenes[@]} -gt 0 ]] || continue
    echo "== $(date -u +%FT%TZ) $k: ${scenes[*]}" >&2
    .venv/bin/regenerate-tables --profile standard --workers 2 --scenes "$(IFS=,; echo "${scenes[*]}")" \
        "${args[@]}" --methods full,rgb-only --seeds 0,1,2 --no-ablations --out "${tables}_$k" "$@" \
        || [[ $? -eq 1 ]]  # 1: tables written, some runs failed (report.md)
done
.venv/bin/python benchmarks/density_sweep.py --datasets "$datasets" --tables "$tables"
