"""Atomic file writes: write a hidden sibling, then rename it into place, so a reader (or a
resumed run) never sees a half-written file."""
from __future__ import annotations

import csv
import dataclasses
import json
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator


def temp_sibling(path: Path) -> Path:
    """The hidden temporary name a file is written under before its rename."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp{path.suffix}")


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``path``, on error it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json(path: Path, data: Any) -> None:
    """Strict JSON (NaN and Inf refused), written atomically."""
    write_text(path, json.dumps(data, indent=2, allow_nan=False) + "\n")


def write_rows_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """One CSV row per dict, the first row's keys as header, written atomically."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def write_dataclass_csv(path: Path, rows: list[Any]) -> None:
    """One CSV row per dataclass instance, the field names as header, written atomically."""
    write_rows_csv(path, [dataclasses.asdict(r) for r in rows])
