"""Reading a run's train_log.csv (docs/results-format.md) for the tables, figures and benchmarks.

Kept apart from contracts.results_format on purpose: the trainer imports that module, so any
change there changes the trainer's code digest and with it the cache key of every finished run;
the trainer never reads its log back this way.
"""
from __future__ import annotations

import csv
from pathlib import Path


def read_train_log(path: Path) -> list[dict[str, str]]:
    """train_log.csv's rows, without those of an attempt that was interrupted and resumed from an
    earlier checkpoint: a row whose (stage, iteration) does not come after the row before it starts
    the resumed attempt, and the rows it repeats are dropped. The resumed rows' wall_s still counts
    the discarded attempt's time (the run did spend it)."""
    kept: list[dict[str, str]] = []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            key = (int(row["stage"]), int(float(row["iteration"])))
            while kept and (int(kept[-1]["stage"]), int(float(kept[-1]["iteration"]))) >= key:
                kept.pop()
            kept.append(row)
    return kept


def stage2_rows(run_dir: Path) -> list[tuple[str, ...]] | None:
    """The Stage-2 rows of a run's train_log.csv without their wall times: what two runs of one
    Stage 2 share when they train it to the same bytes. None where the log is missing or holds no
    Stage-2 row."""
    path = Path(run_dir) / "train_log.csv"
    if not path.is_file():
        return None
    rows = [tuple(v for k, v in row.items() if k != "wall_s") for row in read_train_log(path) if row["stage"] == "2"]
    return rows or None
