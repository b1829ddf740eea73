"""eval.finished_runs on committed runs: one trainer version's finished runs of the variants asked
for, and a script's bad --variants or --digest as one line."""
from __future__ import annotations

from pathlib import Path

import pytest

from eval.finished_runs import pick_digest, runs_of_variants

TABLES = Path(__file__).resolve().parents[1] / "data" / "tables_standard_avx2"


def test_runs_of_variants_reads_one_trainers_runs_and_refuses_bad_input_in_one_line() -> None:
    runs = runs_of_variants(TABLES, "full", ("full", "rgb-only"), "d65d2bcb")
    assert sorted(rec["seed"] for _, rec in runs) == [1, 2]
    assert {rec["scene"] for _, rec in runs} == {"machine"} and all((d / "metrics.json").is_file() for d, _ in runs)
    assert runs_of_variants(TABLES, "rgb-only,full", ("full", "rgb-only"), "d65d2bcb") == runs
    with pytest.raises(SystemExit, match=r"^--variants: unknown fulll \(known: full, rgb-only\)$"):
        runs_of_variants(TABLES, "full,fulll", ("full", "rgb-only"), "d65d2bcb")
    with pytest.raises(SystemExit, match="--digest 00000000: no run in .* has a code_digest starting so .found d65d2bcb"):
        runs_of_variants(TABLES, "full", ("full",), "00000000")


def test_pick_digest_takes_the_prefix_else_the_most_runs() -> None:
    digests = ["aaaa" * 16, "bbbb" * 16, "bbbb" * 16]
    assert pick_digest(digests, None, "F") == "bbbb" * 16 and pick_digest(digests, "aaa", "F") == "aaaa" * 16
    with pytest.raises(ValueError, match=r"^F: no finished run records a code digest$"):
        pick_digest([], "aaa", "F")
