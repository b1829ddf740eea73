#!/usr/bin/env bash
# The standard-profile runs as a work queue, one run per regenerate-tables call, for filling
# the tables over several days, stopped and restarted at will, with two of these side by side.
# Each call says --workers 2, as standard_tables.sh does, so that its one run trains on one thread
# (the harness gives a run cores/workers threads) like every other run of the tables. The order
# puts first what the must-holds read (docs/benchmark.md): Full and RGB-only at seeds 0, 1 and 2;
# "Full, Stage 1 from images" (poses by SfM, masks and smoke presence estimated) at seeds 0-1;
# "Full, estimated Stage 1" at seed 0 (each call plans it beside its cached Full, whose Stage 2 it
# takes); Table 2's ablations at seed 0 (the harness's default list for the standard profile, each
# taking Full's Stage 2 the same way); then each scene's clean ceiling of both at seed 0
# (benchmarks/clean_ceiling.py into data/clean_ceiling_standard; run it once more over every scene
# afterwards for the whole CSV); the DCP baseline at seed 0; "Full, estimated Stage 1" at seeds 1-2;
# seeds 1-2 of each ablation whose seed 0 has finished on every scene close to Full or above it
# (eval/reseed_ablations.py), which a must-hold reads; and last the DCP baseline at seeds 1-2, a
# reference row that no must-hold reads.
# With --density-sweep the queue is issue 49's instead: Full and RGB-only at seeds 0-2 on every
# dataset of data/density_sweep/kK (k = 1 aside, whose runs are Table 1's), seed 0 at every k
# first, each into data/tables_density_kK (benchmarks/density_sweep_plan.sh, shared with
# density_sweep_train.sh, which run with --finished-only afterwards writes the tables and curves).
# A worker claims a step by creating its folder under CLAIMS (mkdir is atomic; the step's log
# goes there) and writing its process id and start time (clock ticks after boot, which a reset
# of the wall clock does not move) into it, so two workers never train the same run; cached
# steps cost seconds. A step's folder gets a `done` file when its call returns.
# A claim without `done` whose owner has gone (the machine restarted, the worker was killed) is
# stale: the next worker to reach it renames it away (rename is atomic, so only one worker
# succeeds), says so, and claims the step afresh; the run resumes from its checkpoint.
# A worker plans afresh before each step, so the sweep's list takes up the datasets generated
# meanwhile, seed 0 first. A worker stops before its next step once CLAIMS/STOP exists. Afterwards,
# `bash benchmarks/standard_tables.sh --finished-only` writes the tables.
#
#   bash benchmarks/standard_tables_queue.sh [--density-sweep] NAME [CLAIMS]   (CLAIMS default: runs/claims)
set -euo pipefail
cd "$(dirname "$0")/.."
plan=standard
if [[ ${1:-} == --density-sweep ]]; then plan=density-sweep; shift; fi
name=${1:?usage: standard_tables_queue.sh [--density-sweep] NAME [CLAIMS]}
claims=${2:-runs/claims}
root=data/standard
out=data/tables_standard
sweep=data/density_sweep
sweep_tables=data/tables_density
ceilings=data/clean_ceiling_standard
mkdir -p "$claims"
started_ticks() {  # started_ticks PID: its start in clock ticks after boot (/proc/PID/stat field 22);
    # unlike ps's lstart, which is derived from the wall clock, it does not move when the clock is set
    local stat fields
    stat=$(cat "/proc/$1/stat" 2>/dev/null) || return 1
    stat=${stat##*) }  # the fields after the command name, which may hold spaces
    read -r -a fields <<< "$stat"
    echo "${fields[19]}"
}
me="$$ $(started_ticks $$)"
alive() {  # alive CLAIM: its owner process still runs (same pid and start)
    local pid started
    read -r pid started 2>/dev/null < "$1/owner" || return 1
    [[ -n $started && "$(started_ticks "$pid")" == "$started" ]]
}
take() {  # take CLAIM: claim the step, or take over a stale claim of it
    if mkdir "$1" 2>/dev/null; then echo "$me" > "$1/owner"; return 0; fi
    [[ -e $1/done ]] && return 1
    sleep 1  # a claim just made may not have its owner file yet
    alive "$1" && return 1
    local stale; stale="$1.stale.$(date -u +%Y%m%dT%H%M%SZ).$$"
    mv -T "$1" "$stale" 2>/dev/null || return 1
    echo "[$name] $(date -u +%FT%TZ) stale claim taken over ($(cat "$stale/owner" 2>/dev/null || echo no owner)): $stale"
    mkdir "$1" 2>/dev/null || return 1
    echo "$me" > "$1/owner"
}
source benchmarks/standard_scenes.sh
source benchmarks/density_sweep_plan.sh
mapfile -t scenes < <(standard_scenes "$root")
ablations=$(.venv/bin/python -c \
    "from eval.settings import default_ablations; print(*default_ablations('standard', {}), sep='\n')")
mapfile -t ablations <<< "$ablations"
add_steps() {  # add_steps METHODS SEED [ABLATION]: one step per scene
    local s
    for s in "${scenes[@]}"; do steps+=("$s $1 $2 ${3:--}"); done
}
plan_steps() {  # fills steps
    steps=()
    if [[ $plan == standard ]]; then
        for seed in 0 1 2; do add_steps full "$seed"; add_steps rgb-only "$seed"; done
        for seed in 0 1; do add_steps full,full-from-images "$seed"; done
        add_steps full,full-estimated 0
        for a in "${ablations[@]}"; do add_steps full 0 "$a"; done
        add_steps ceiling:full 0; add_steps ceiling:rgb-only 0
        add_steps imgdehaze-dcp 0
        local close  # a failure of the rule stops the worker (set -e), never an empty list
        close=$(.venv/bin/python -m eval.reseed_ablations "$out" --scenes "$(IFS=,; echo "${scenes[*]}")")
        read -r -a reseed <<< "${close//$'\n'/ }"
        for seed in 1 2; do add_steps full,full-estimated "$seed"; done
        for seed in 1 2; do for a in "${reseed[@]}"; do add_steps full "$seed" "$a"; done; done
        for seed in 1 2; do add_steps imgdehaze-dcp "$seed"; done
        return
    fi
    local k s m
    mapfile -t datasets < <(sweep_datasets "$sweep")
    for seed in "${sweep_seeds[@]}"; do  # SCENE METHOD SEED - kK: the dataset is $sweep/kK/SCENE
        for entry in "${datasets[@]}"; do
            read -r k s <<< "$entry"
            [[ $k == k1 ]] && continue
            for m in "${sweep_methods[@]}"; do steps+=("$s $m $seed - $k"); done
        done
    done
}
while :; do  # each step planned afresh: the first of the plan that can be claimed
    if [[ -e "$claims/STOP" ]]; then echo "[$name] $(date -u +%FT%TZ) STOP found, leaving"; exit 0; fi
    plan_steps
    step=""
    for candidate in "${steps[@]}"; do
        claim="$claims/$(echo "$candidate" | md5sum | cut -c1-12)"
        if take "$claim"; then step=$candidate; break; fi
    done
    [[ -n $step ]] || break
    read -r scene method seed ablation k <<< "$step"
    dataset=$root/$scene tables=$out
    if [[ -n $k ]]; then dataset=$sweep/$k/$scene tables=${sweep_tables}_$k; fi
    if [[ $ablation == - ]]; then which=(--no-ablations); else which=(--ablations --ablation-list "$ablation"); fi
    echo "[$name] $(date -u +%FT%TZ) start $step"
    t0=$SECONDS
    rc=0
    if [[ $method == ceiling:* ]]; then
        .venv/bin/python benchmarks/clean_ceiling.py "$root/$scene" --modes "${method#ceiling:}" --seed "$seed" \
            --out "$ceilings" --csv "$claim/clean_ceiling.csv" > "$claim/log" 2>&1 || rc=$?
    else
        .venv/bin/regenerate-tables --profile standard --workers 2 --scenes "$scene" --dataset "$scene=$dataset" \
            --methods "$method" --seeds "$seed," "${which[@]}" --out "$tables" > "$claim/log" 2>&1 || rc=$?
    fi
    echo "$rc" > "$claim/done"
    echo "[$name] $(date -u +%FT%TZ) done $step rc=$rc $((SECONDS - t0)) s"
done
echo "[$name] $(date -u +%FT%TZ) queue empty"
