#!/usr/bin/env bash
# Choosing the trainer's rules on a distribution (rules issue, item 4): Full, RGB-only and the rule
# candidates (eval/runs.py, CANDIDATES) at seed 0, in three resumable regenerate-tables calls, and
# the reports that read them.
#
#   bash benchmarks/rules_choice.sh proxy-standard   the ten standard scenes at the proxy profile
#   bash benchmarks/rules_choice.sh standard         the ten standard scenes at the standard profile,
#                                                    into data/tables_standard (Table 1's seed-0 runs
#                                                    of today's trainer; the plane field beside them)
#   bash benchmarks/rules_choice.sh proxy-dev        random-dev at the proxy profile
#   bash benchmarks/rules_choice.sh report DIGEST    proxy against standard on the ten scenes, and the
#                                                    candidates on random-dev's validation views
#
# The proxy is the standard profile at a quarter of the pixels (80 px wide) and a third of the
# iterations (1000 + 1000): about 2 minutes a run on a drawn scene, against about 13 at the
# standard profile. A choice made at the proxy counts only where the proxy ranks the candidates as
# the standard profile does on the ten standard scenes (benchmarks/proxy_ranking.py).
# Extra arguments go to regenerate-tables (e.g. --dry-run).
set -euo pipefail
cd "$(dirname "$0")/.."
CANDIDATES=start-thermal,start-clear-views
PROXY=(--set max_width=80 --set stage2.iterations=1000 --set stage3.iterations=1000)
RESULTS=benchmarks/results/rules
step=${1:-}
shift || true
source benchmarks/standard_scenes.sh
standard_plan() {  # standard_plan OUT [options]: Full, RGB-only and the candidates on the ten scenes
    local out=$1; shift
    mapfile -t scenes < <(standard_scenes data/standard)
    local datasets=() s
    for s in "${scenes[@]}"; do datasets+=(--dataset "$s=data/standard/$s"); done
    local list; list=$(IFS=,; echo "${scenes[*]}")
    .venv/bin/regenerate-tables --profile standard --workers 2 --methods full,rgb-only --seeds 0, --no-ablations \
        --scenes "$list" "${datasets[@]}" --out "$out" "$@" || [[ $? -eq 1 ]]  # 1: tables written, some runs failed
}
case $step in
    proxy-standard) standard_plan data/tables_rules_proxy --candidates "$CANDIDATES" "${PROXY[@]}" "$@" ;;
    standard) standard_plan data/tables_standard --candidates "$CANDIDATES,motion-planes" "$@" ;;
    proxy-dev) bash benchmarks/random_set_tables.sh data/random_dev data/tables_random_dev_proxy \
                   --candidates "$CANDIDATES" "${PROXY[@]}" "$@" ;;
    report)
        [[ $# -ge 1 ]] || { echo "usage: bash benchmarks/rules_choice.sh report DIGEST" >&2; exit 2; }
        .venv/bin/python benchmarks/proxy_ranking.py --standard data/tables_standard --proxy data/tables_rules_proxy \
            --variants "full,${CANDIDATES}" --digest "$1" --out "$RESULTS/proxy_ranking.csv"
        .venv/bin/python benchmarks/random_set_scores.py --tables data/tables_random_dev_proxy \
            --datasets data/random_dev --split val --digest "$1" --candidates "$CANDIDATES" \
            --out "$RESULTS/random_dev_proxy_val.csv" --summary "$RESULTS/random_dev_proxy_rules_val.csv" ;;
    *) echo "usage: bash benchmarks/rules_choice.sh proxy-standard|standard|proxy-dev|report DIGEST [options]" >&2
       exit 2 ;;
esac
