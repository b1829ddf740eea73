# Sourced by standard_tables.sh and standard_tables_queue.sh: the benchmark's scenes, in the
# order the tables are filled, whose standard dataset exists under a root, so both scripts
# train the same scenes in the same order.
standard_scenes() {  # standard_scenes ROOT: prints one scene per line
    local s
    for s in house room forest food_plate excavator rover chair plant brick_toy machine; do
        if [[ -f "$1/$s/dataset.json" ]]; then echo "$s"; fi
    done
}
