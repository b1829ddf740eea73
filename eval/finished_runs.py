"""The finished runs of one trainer version in a tables folder, for the studies that read a
table's runs back (Stage-2 sharing, the best-validation snapshot, the smoke-colour decisions).

Why one place: a tables folder keeps the runs of every trainer version it has seen (keyed by the
code digest), and a study must read one version's runs only, the same way each time.
"""
from __future__ import annotations

import collections
import json
from pathlib import Path
from typing import Any, Iterable


def finished_runs(tables: Path, variants: Iterable[str],
                  digest: str | None = None) -> tuple[str, list[tuple[Path, dict[str, Any]]]]:
    """(the chosen code digest, [(run folder, harness.json record)]) for the runs of ``variants``
    that finished (status ok, with a train_log.csv) under one trainer version: the one whose
    digest starts with ``digest``, else the one with the most such runs. Raises ValueError naming
    the folder when there is none."""
    wanted = set(variants)
    records = finished_records(tables, wanted)
    if not records:
        raise ValueError(f"{tables}/runs: no finished run of {', '.join(sorted(wanted))} records a code_digest")
    chosen = pick_digest([rec["code_digest"] for _, rec in records], digest, f"{tables}/runs")
    return chosen, [(run_dir, rec) for run_dir, rec in records if rec["code_digest"] == chosen]


def runs_by_version(tables: Path, variants: Iterable[str], seed: int
                    ) -> dict[tuple[str, str], dict[str, tuple[Path, dict[str, Any]]]]:
    """The finished runs of ``variants`` at ``seed``, by (scene, code digest) and then variant: what
    a study pairing two folders' runs reads, so that a scene's runs are compared under one trainer."""
    found: dict[tuple[str, str], dict[str, tuple[Path, dict[str, Any]]]] = {}
    for run, rec in finished_records(tables, variants):
        if rec["seed"] == seed:
            found.setdefault((rec["scene"], rec["code_digest"]), {})[rec["variant"]] = (run, rec)
    return found


def finished_records(tables: Path, variants: Iterable[str]) -> list[tuple[Path, dict[str, Any]]]:
    """[(run folder, harness.json record)] of every finished run of ``variants`` that records its
    code digest, whatever the trainer version (a study pairing runs by version picks its own)."""
    wanted = set(variants)
    records = []
    for path in sorted((Path(tables) / "runs").glob("*/*/*/harness.json")):
        rec = json.loads(path.read_text())
        if (rec.get("status") == "ok" and rec.get("variant") in wanted and rec.get("code_digest")
                and (path.parent / "train_log.csv").is_file()):
            records.append((path.parent, rec))
    return records


def pick_digest(digests: Iterable[str], digest: str | None, where: str) -> str:
    """The trainer version to read, from the code digests of the finished runs in ``where`` (one
    per run): the one that starts with ``digest``, else the one with the most runs. Raises
    ValueError naming ``where`` and the versions found when none starts so, or there is none."""
    versions = collections.Counter(digests)
    if not versions:
        raise ValueError(f"{where}: no finished run records a code digest")
    chosen = next((v for v in versions if v.startswith(digest)), None) if digest else versions.most_common(1)[0][0]
    if chosen is None:
        raise ValueError(f"--digest {digest}: no run in {where} has a code_digest starting so "
                         f"(found {', '.join(v[:8] for v in versions)})")
    return chosen


def runs_of_variants(tables: Path, variants: str, known: Iterable[str],
                     digest: str | None) -> list[tuple[Path, dict[str, Any]]]:
    """``finished_runs`` for a script's comma list of variants: a variant not in ``known``, or no
    finished run, is one line (SystemExit), never a traceback."""
    known = tuple(known)
    unknown = sorted(set(variants.split(",")) - set(known))
    if unknown:
        raise SystemExit(f"--variants: unknown {', '.join(unknown)} (known: {', '.join(known)})")
    try:
        return finished_runs(tables, variants.split(","), digest)[1]
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
