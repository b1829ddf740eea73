"""The OpenMP spin count the package sets before torch loads libgomp (smokeseer/__init__.py)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Records the spin count in the environment at the moment anything first imports torch (when torch's
# libgomp is loaded and reads it), then imports the train-and-evaluate CLI the way its script does.
PROBE = """
import importlib.abc, os, sys
seen = []
class Probe(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "torch" and not seen:
            seen.append(os.environ.get("GOMP_SPINCOUNT", "unset"))
        return None
sys.meta_path.insert(0, Probe())
import smokeseer.cli
smokeseer.cli.main  # the CLI module is complete
import torch
print(seen[0])
"""


def _spin_count_when_torch_loads(env: dict[str, str]) -> str:
    done = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, env=env, capture_output=True, text=True,
                          check=True)
    return done.stdout.strip()


def test_cli_import_bounds_the_spin_before_torch_unless_told_otherwise() -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    env["PYTHONPATH"] = str(ROOT)
    assert _spin_count_when_torch_loads(env) == "10000"
    assert _spin_count_when_torch_loads({**env, "GOMP_SPINCOUNT": "5"}) == "5"
    assert _spin_count_when_torch_loads({**env, "OMP_WAIT_POLICY": "PASSIVE"}) == "unset"
