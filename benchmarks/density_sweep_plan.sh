# Sourced by density_sweep_train.sh and standard_tables_queue.sh: issue 49's runs, so that the
# one-call script and the queue train the same runs and key them the same way. The runs of
# DATASETS/kK/SCENE go to TABLES_kK (regenerate-tables' keying, data/README.md); those of k = 1
# are Table 1's runs of the standard dataset, linked rather than trained.
sweep_methods=(full rgb-only)
sweep_seeds=(0 1 2)
sweep_datasets() {  # sweep_datasets DATASETS: "kK SCENE" per generated dataset, in folder order
    local d
    for d in "$1"/k*/*/dataset.json; do
        [[ -f $d ]] || continue
        d=${d%/dataset.json}
        echo "$(basename "$(dirname "$d")") $(basename "$d")"
    done
}
