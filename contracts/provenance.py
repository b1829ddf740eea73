"""Where a result came from: the code's commit (or its version and source digest outside git),
the thread count and the machine. Written into metrics.json and results.json."""
from __future__ import annotations

import os
import platform
import subprocess
from importlib import metadata

from contracts.float_setup import float_setup
from contracts.source import PROJECT_ROOT, code_digest


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(["git", "-C", str(PROJECT_ROOT), *args], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def code_version() -> dict[str, object]:
    """The commit and whether tracked files differ from it; outside a git checkout the commit is
    None and the package version stands in (the source digest is recorded either way)."""
    commit = _git("rev-parse", "HEAD") if (PROJECT_ROOT / ".git").exists() else None
    status = _git("status", "--porcelain", "--untracked-files=no") if commit else None
    try:
        version = metadata.version("smokeseer-synth")
    except metadata.PackageNotFoundError:
        version = "not installed"
    return {"commit": commit, "dirty": bool(status) if commit else None, "version": version}


def machine() -> dict[str, object]:
    return {"host": platform.node(), "system": platform.system(), "arch": platform.machine(),
            "processor": platform.processor() or "unknown", "cpu_count": os.cpu_count(),
            "python": platform.python_version(), "float_setup": float_setup()}


def provenance(entry_module: str, threads: int) -> dict[str, object]:
    """Provenance of a result made by ``entry_module`` (its import closure is digested)."""
    return {**code_version(), "source_digest": code_digest(entry_module), "entry": entry_module,
            "threads": threads, "machine": machine()}
