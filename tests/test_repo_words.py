"""The repository speaks of the project to its users, never of the machine it was built on.

Every tracked text file is read (``git ls-files``): docs, code, tests, scripts, configs, presets,
committed results and dataset metadata. A file counts as text unless its suffix is a known binary
image or model format or its bytes hold a NUL. The run records are left out: those under
``data/tables_*/runs/``, ``data/input_perturbation/tables/runs/``, ``data/float_setup/*/runs/``,
``data/clean_ceiling_*/`` and ``data/candidates/``. They are what each
training run wrote (its ``metrics.json``, and the harness's ``harness.json``), including the
dataset path it was given and that machine's LPIPS message; the harness re-roots those paths on
load, and rewriting a record by hand would make it no longer the run's own.

Forbidden: the word for a working sitting of the people who built the project (also inside code
identifiers), the words for borrowing a machine for a while, and the absolute folders of that
machine. The words are assembled from pieces below so that this file does not match itself.
"""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

_SITTING_WORD = "sess" + "ion"
_RENTAL_STEM = "lea" + "s"
_BORROWED_WORD = "le" + "nt"
FORBIDDEN = re.compile(
    "|".join([
        rf"(?<![a-z]){_SITTING_WORD}",  # inside identifiers too: start_new_<word>, <Word>Factory
        rf"(?<![a-z]){_RENTAL_STEM}(?:e|es|ed|ing)(?![a-z])",  # not "release", "please"
        rf"(?<![a-z]){_BORROWED_WORD}(?![a-z])",  # not "talent", "silent"
        *(re.escape(f"/{d}/") for d in ("wo" + "rk", "ro" + "ot", "t" + "mp")),
    ]),
    re.IGNORECASE,
)
BINARY_SUFFIXES = {".png", ".jpg", ".jpeg", ".exr", ".ply", ".npy", ".npz", ".pt", ".blend", ".vdb"}
RUN_RECORDS = re.compile(r"^data/(tables_[^/]+/runs|input_perturbation/tables/runs|float_setup/[^/]+/runs|clean_ceiling_[^/]+|candidates)/")


def _tracked_text_files() -> list[Path]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the tracked files cannot be listed")
    names = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, check=True, capture_output=True).stdout
    files = []
    for name in names.decode().split("\0"):
        path = ROOT / name
        if name and not RUN_RECORDS.match(name) and path.suffix.lower() not in BINARY_SUFFIXES and path.is_file():
            files.append(path)
    return files


def test_the_matcher_catches_the_words_and_spares_their_neighbours() -> None:
    caught = [f"one {_SITTING_WORD}", f"two {_SITTING_WORD}s", f"Popen(start_new_{_SITTING_WORD}=True)", f"a {_BORROWED_WORD} GPU",
              f"a 15-minute {_RENTAL_STEM}e", f"{_RENTAL_STEM}ed machines", "/" + "tmp/x", "cp /" + "work/main/x ."]
    spared = ["talent", "silent", "release", "released", "please", "possession", "temp_dir", "network/"]
    assert all(FORBIDDEN.search(s) for s in caught), [s for s in caught if not FORBIDDEN.search(s)]
    assert not any(FORBIDDEN.search(s) for s in spared), [s for s in spared if FORBIDDEN.search(s)]


def test_no_tracked_file_speaks_of_the_build_machine() -> None:
    files = _tracked_text_files()
    assert len(files) > 100, "git ls-files listed almost nothing"
    hits = []
    for path in files:
        data = path.read_bytes()
        if b"\0" in data:
            continue
        for lineno, line in enumerate(data.decode("utf-8", errors="replace").splitlines(), 1):
            m = FORBIDDEN.search(line)
            if m:
                hits.append(f"{path.relative_to(ROOT)}:{lineno}: {m.group(0)!r} in {line.strip()[:100]!r}")
    assert not hits, f"{len(hits)} line(s) speak of the build machine:\n" + "\n".join(hits[:60])
