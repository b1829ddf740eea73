#!/usr/bin/env bash
# Full and RGB-only on every finished scene of a drawn set (generate-benchmark --random), at one
# seed, into one tables folder: what a rule is chosen on (random-dev, validation views) and what is
# reported once (random-test, test views). One regenerate-tables call, so a stopped run resumes
# (finished runs from the cache, an interrupted one from its checkpoint), and scenes generated
# meanwhile join at the next call. Then the per-scene comparison:
#
#   bash benchmarks/random_set_tables.sh SET OUT [--first N | --only SCENE,...] [regenerate-tables options, e.g. --set KEY=VALUE or --dry-run]
#
# --first N: only the first N finished scenes (by name), so that a long plan can be filled in
# waves of whole scenes (the harness runs every Stage-2 leader before the runs that take one).
# --only SCENE,...: only these scenes (a screen of candidates on scenes spread over optical depth);
# one that is not a finished scene of SET is refused before any work.
#   python benchmarks/random_set_scores.py --tables OUT --datasets SET --out CSV [--split val]
#
# Defaults: the standard profile, seed 0, two workers of one thread.
set -euo pipefail
cd "$(dirname "$0")/.."
if [[ $# -lt 2 ]]; then
    echo "usage: bash benchmarks/random_set_tables.sh SET OUT [regenerate-tables options]" >&2
    exit 2
fi
set_root=$1
out=$2
shift 2
first=0 only=
if [[ ${1:-} == --first ]]; then first=$2; shift 2; fi
if [[ ${1:-} == --only ]]; then only=$2; shift 2; fi
mapfile -t scenes < <(find "$set_root" -mindepth 2 -maxdepth 2 -name dataset.json -path '*/random_*/dataset.json' \
                       -printf '%h\n' | xargs -r -n1 basename | sort)
if [[ $first -gt 0 ]]; then scenes=("${scenes[@]:0:first}"); fi
if [[ -n $only ]]; then
    IFS=, read -ra wanted <<< "$only"
    for s in "${wanted[@]}"; do
        if [[ ! " ${scenes[*]} " == *" $s "* ]]; then
            echo "random_set_tables.sh: --only: $s is not a finished scene of $set_root" >&2
            exit 2
        fi
    done
    scenes=("${wanted[@]}")
fi
if [[ ${#scenes[@]} -eq 0 ]]; then
    echo "random_set_tables.sh: no finished drawn scene (random_*/dataset.json) under $set_root" >&2
    exit 2
fi
datasets=()
for s in "${scenes[@]}"; do datasets+=(--dataset "$s=$set_root/$s"); done
list=$(IFS=,; echo "${scenes[*]}")
echo "== $(date -u +%FT%TZ) ${#scenes[@]} scenes of $set_root into $out" >&2
.venv/bin/regenerate-tables --profile standard --workers 2 --methods full,rgb-only --seeds 0, --no-ablations \
    --scenes "$list" "${datasets[@]}" --out "$out" "$@" || [[ $? -eq 1 ]]  # 1: tables written, some runs failed
