"""Cache keys follow the code a task runs: the project modules its entry point imports,
digested without docstrings and comments. Checked on a copy of this project's own source."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import contracts.source as source
from contracts.source import (DIGEST_CACHE_ENV, PROJECT_ROOT, code_digest, code_fingerprint, digest_cache_path,
                              module_closure)

TRAINER = "smokeseer.api"


@pytest.fixture()
def tree(tmp_path: Path) -> Path:
    for pkg in ("contracts", "scenes", "smokeseer", "eval"):
        shutil.copytree(PROJECT_ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__", "build"))
    return tmp_path


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert text.count(old) >= 1, f"{path}: {old!r} not found"
    path.write_text(text.replace(old, new, 1))


def test_closure_follows_imports_into_other_packages(tree: Path) -> None:
    names = {m.name for m in module_closure(TRAINER, root=tree)}
    assert {"smokeseer.train.stage3", "smokeseer.raster", "scenes.load", "contracts.metrics", "contracts.dataset_format"} <= names
    assert not any(n.startswith("eval") for n in names)


def test_docstring_and_comment_edits_keep_the_key(tree: Path) -> None:
    before = code_digest(TRAINER, root=tree)
    stage3 = tree / "smokeseer" / "train" / "stage3.py"
    _edit(stage3, '"""Stage 3: surface and smoke, jointly.', '"""Stage 3: surface and smoke, trained jointly.')
    _edit(stage3, "from __future__ import annotations\n", "from __future__ import annotations  # a comment\n\n")
    assert code_digest(TRAINER, root=tree) == before


def test_code_edit_in_an_imported_module_changes_the_key(tree: Path) -> None:
    before = code_digest(TRAINER, root=tree)
    _edit(tree / "contracts" / "metrics.py", "PSNR_CAP_DB = 100.0", "PSNR_CAP_DB = 99.0")
    assert code_digest(TRAINER, root=tree) != before


def test_edit_in_a_module_the_task_does_not_import_keeps_the_key(tree: Path) -> None:
    before = code_digest(TRAINER, root=tree)
    _edit(tree / "eval" / "tables.py", "import csv\n", "import csv\nUNUSED_BY_THE_TRAINER = 1\n")
    assert code_digest(TRAINER, root=tree) == before
    assert code_digest("eval.tables", root=tree) != code_digest("eval.tables")


def test_kernel_sources_shipped_in_a_package_count(tree: Path) -> None:
    before = code_digest(TRAINER, root=tree)
    (tree / "smokeseer" / "raster" / "csrc").mkdir(exist_ok=True)
    (tree / "smokeseer" / "raster" / "csrc" / "probe_kernel.cpp").write_text("int probe() { return 1; }\n")
    assert code_digest(TRAINER, root=tree) != before


def test_fingerprint_ignores_layout_but_not_values(tmp_path: Path) -> None:
    a, b, c = tmp_path / "a.py", tmp_path / "b.py", tmp_path / "c.py"
    a.write_text('def f(x):\n    """Doc."""\n    return x + 1\n')
    b.write_text("def f(x):  # comment\n\n    return (x +\n            1)\n")
    c.write_text("def f(x):\n    return x + 2\n")
    assert code_fingerprint(a) == code_fingerprint(b) != code_fingerprint(c)


def test_unknown_entry_point_is_an_error() -> None:
    with pytest.raises(ValueError, match="no project module named 'smokeseer.nope'"):
        code_digest("smokeseer.nope")


def test_remembered_digest_equals_the_computed_one_and_follows_edits(tree: Path, tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    cache = tmp_path / "cache" / "digests.json"
    monkeypatch.setenv(DIGEST_CACHE_ENV, str(cache))
    assert digest_cache_path() == cache
    first = code_digest(TRAINER, root=tree)
    assert first == source._computed_digest(TRAINER, root=tree) and cache.is_file()
    calls: list[tuple[str, ...]] = []
    computed = source._computed_digest
    monkeypatch.setattr(source, "_computed_digest", lambda *r, root: calls.append(r) or computed(*r, root=root))
    assert code_digest(TRAINER, root=tree) == first and not calls
    _edit(tree / "smokeseer" / "train" / "losses.py", "def ", "def _unused() -> None:\n    pass\n\n\ndef ")
    edited = code_digest(TRAINER, root=tree)
    assert calls == [(TRAINER,)] and edited != first and edited == computed(TRAINER, root=tree)
    cache.write_text("{not json")
    assert code_digest(TRAINER, root=tree) == edited and len(calls) == 2


def test_empty_cache_setting_turns_the_cache_off(tree: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(DIGEST_CACHE_ENV, "")
    assert digest_cache_path() is None
    assert code_digest(TRAINER, root=tree) == source._computed_digest(TRAINER, root=tree)
