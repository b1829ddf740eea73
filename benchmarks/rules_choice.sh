#!/usr/bin/env bash
# Choosing the trainer's settings on a distribution (rules issue, item 4; the motion issue's sweep):
# Full beside the candidates of eval/runs.py (CANDIDATES) at seed 0 and the standard profile, each
# step one resumable regenerate-tables call, and the report that reads them. Candidates that change
# Stage 3 only take Full's finished Stage 2.
#
#   bash benchmarks/rules_choice.sh motion      the ten standard scenes: Full and the plane field
#                                               (into data/tables_standard, beside Table 1's runs)
#   bash benchmarks/rules_choice.sh standard [--methods full]   the ten standard scenes: Full,
#                                               RGB-only and the rule candidates (into
#                                               data/tables_standard); --methods full as below
#   bash benchmarks/rules_choice.sh dev [--first N | --only SCENE,...] [--methods full]   random-dev:
#                                               the same (into data/tables_random_dev), the first N
#                                               scenes only with --first, the named ones with --only
#                                               (a screen over optical depth); --methods full leaves
#                                               RGB-only out (the choice reads Full and the candidates)
#   bash benchmarks/rules_choice.sh report DIGEST   the per-scene comparisons, validation views, into
#                                               CSVs named by the first 8 digits of DIGEST
#
# RULES (the environment) names the candidates; by default the trainer's current wave. The report
# reads finished runs by name, so an earlier wave's report runs again with its names, though a
# candidate that was not adopted has left eval/runs.py:
#   RULES=start-thermal,start-clear-views,mask-bound bash benchmarks/rules_choice.sh report ba3c3d79
#   RULES=rgb-start-clear-pixels,rgb-start-clear-views bash benchmarks/rules_choice.sh report 580fa3b5
#   RULES=thermal-box-filtered,carve-where-smoky,floor-by-meeting-trust bash benchmarks/rules_choice.sh report 6348cb72
#
# A shorter Stage 3 does not stand in for the standard profile: at 1000 + 1000 iterations and 80 px
# every route left food_plate 6-8 dB under its smoky input, where the standard Full ends 0.6 dB over
# it after climbing from 17.8 dB at iteration 1000 (docs/experiments/2026-12-05-choosing-rules.md).
# Extra arguments go to regenerate-tables (e.g. --dry-run).
set -euo pipefail
cd "$(dirname "$0")/.."
RULES=${RULES:-carve-where-smoky,floor-by-meeting-trust}
RESULTS=benchmarks/results/rules
step=${1:-}
shift || true
source benchmarks/standard_scenes.sh
standard_plan() {  # standard_plan METHODS CANDIDATES [options]: the ten standard scenes at seed 0
    local methods=$1 candidates=$2; shift 2
    mapfile -t scenes < <(standard_scenes data/standard)
    local datasets=() s
    for s in "${scenes[@]}"; do datasets+=(--dataset "$s=data/standard/$s"); done
    local list; list=$(IFS=,; echo "${scenes[*]}")
    .venv/bin/regenerate-tables --profile standard --workers 2 --methods "$methods" --candidates "$candidates" \
        --seeds 0, --no-ablations --scenes "$list" "${datasets[@]}" --out data/tables_standard "$@" \
        || [[ $? -eq 1 ]]  # 1: tables written, some runs failed
}
case $step in
    motion) standard_plan full motion-planes "$@" ;;
    standard) standard_plan full,rgb-only "$RULES" "$@" ;;
    dev) bash benchmarks/random_set_tables.sh data/random_dev data/tables_random_dev "$@" --candidates "$RULES" ;;
    report)
        [[ $# -ge 1 ]] || { echo "usage: bash benchmarks/rules_choice.sh report DIGEST" >&2; exit 2; }
        for set in standard random_dev; do
            tables=data/tables_$set
            if ! grep -rqs --include=harness.json "\"code_digest\": \"$1" "$tables/runs"; then
                echo "rules_choice: no run of trainer $1 in $tables/runs: $set left out" >&2
                continue
            fi
            .venv/bin/python benchmarks/random_set_scores.py --tables "$tables" --datasets "data/$set" \
                --split val --digest "$1" --candidates "$RULES" \
                --out "$RESULTS/${set}_val-${1:0:8}.csv" --summary "$RESULTS/${set}_rules_val-${1:0:8}.csv"
        done ;;
    *) echo "usage: bash benchmarks/rules_choice.sh motion|standard|dev|report DIGEST [options]" >&2
       exit 2 ;;
esac
