"""How a path is written into a record that may be committed (metrics.json, harness.json), and read back.

A path inside the project is recorded relative to the project root, so a record says the same
on every clone and tells nothing of the machine it was made on; a path outside the project (a
user's own capture) is recorded as given, resolved. Reading resolves a relative path against
the project root, wherever the reader runs from.
"""
from __future__ import annotations

from pathlib import Path

from contracts.source import PROJECT_ROOT


def recorded_path(path: str | Path) -> str:
    """``path`` as a record holds it ("" stays "")."""
    if not str(path):
        return ""
    p = Path(path).resolve()
    try:
        return p.relative_to(PROJECT_ROOT).as_posix()
    except ValueError:
        return str(p)


def recorded_location(text: str) -> Path:
    """The file or folder a record's path names."""
    p = Path(text)
    return p if p.is_absolute() else PROJECT_ROOT / p
