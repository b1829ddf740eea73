"""No import circle between files, and the harness and converters use only the trainer's public API.

The graph has one node per ``.py`` file of the tree (the project packages, ``tests/``,
``benchmarks/``, ``scripts/``; hidden folders and build output left out) and an edge for every
import statement wherever it sits (module level or inside a function: a lazy import back is a
circle too). An import names a file by Python's rules: ``import a.b`` and ``from a import b``
reach ``a/b.py`` when that file exists, else ``a/__init__.py``; relative imports are resolved
against the importing file's package; and every package ``__init__.py`` on the way runs, so it
is an edge too (except the importer's own packages, which are already running).

**Public trainer API**, the only trainer modules ``interop/`` and ``eval/`` may import:
``smokeseer`` (the package), ``smokeseer.api`` (``prepare``, ``train_and_evaluate``),
``smokeseer.config`` (profiles, options, ``make_config``) and ``smokeseer.train.plan`` (the Stage 3
plan a run records in metrics.json; torch-free), with ``smokeseer.train``, the package on the way
to it (its ``__init__`` holds only a docstring). Everything else under ``smokeseer/`` is internal;
scenes are read through ``scenes``, never through the trainer.
"""
from __future__ import annotations

import ast
from pathlib import Path

from contracts.source import import_statements
from tests.test_packages import find_cycle

ROOT = Path(__file__).resolve().parents[1]
PUBLIC_TRAINER_API = frozenset({"smokeseer", "smokeseer.api", "smokeseer.config", "smokeseer.train",
                                "smokeseer.train.plan"})
TRAINER_CLIENTS = ("interop", "eval")
SKIPPED_PARTS = {"__pycache__", "build", "dist", "runs", "node_modules"}


def source_files(root: Path) -> dict[str, tuple[Path, bool]]:
    """Dotted module name → (file, is a package ``__init__``) for every .py file under ``root``."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if any(part.startswith(".") or part in SKIPPED_PARTS or part.endswith(".egg-info") for part in rel.parts):
            continue
        parts = list(rel.with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        if parts:
            out[".".join(parts)] = (path, is_package)
    return out


def import_graph(root: Path) -> dict[str, dict[str, int]]:
    """Module → {imported module: the line of the first import that reaches it}."""
    files = source_files(root)
    graph: dict[str, dict[str, int]] = {}
    for name, (path, is_package) in files.items():
        own = {".".join(name.split(".")[:i]) for i in range(1, name.count(".") + 2)}
        edges = graph.setdefault(name, {})
        for dotted, line in import_statements(ast.parse(path.read_text(), filename=str(path)),
                                             name if is_package else name.rpartition(".")[0]):
            parts = dotted.split(".")
            reached = [".".join(parts[:i]) for i in range(1, len(parts) + 1) if ".".join(parts[:i]) in files]
            for target in reached:
                if target not in own:
                    edges.setdefault(target, line)
    return graph


def internal_trainer_imports(graph: dict[str, dict[str, int]]) -> list[str]:
    """``module:line imports target`` for every import of a trainer-internal module from interop/ or eval/."""
    return [f"{src}:{line} imports {dst}" for src, deps in sorted(graph.items())
            if src.split(".")[0] in TRAINER_CLIENTS
            for dst, line in sorted(deps.items())
            if dst.split(".")[0] == "smokeseer" and dst not in PUBLIC_TRAINER_API]


def _describe(graph: dict[str, dict[str, int]], cycle: list[str]) -> str:
    return " -> ".join(f"{a} (line {graph[a][b]} imports {b})" for a, b in zip(cycle, cycle[1:]))


def test_no_import_circle_between_files() -> None:
    graph = import_graph(ROOT)
    assert {"scenes.load", "smokeseer.api", "tests.test_import_graph"} <= graph.keys()
    cycle = find_cycle(graph)
    assert cycle is None, f"import circle between files: {_describe(graph, cycle)}"


def test_harness_and_converters_use_only_the_public_trainer_api() -> None:
    graph = import_graph(ROOT)
    assert {"smokeseer.config", "smokeseer.train.plan"} <= graph["eval.settings"].keys()  # it sees the harness
    assert internal_trainer_imports(graph) == []


def test_the_checks_fail_on_a_circle_and_on_an_internal_import(tmp_path: Path) -> None:
    """The checker itself, on a small tree: a lazy import back through a package's ``__init__``
    and a relative import are circles; the harness reaching into a trainer stage is flagged."""
    files = {
        "pkg/__init__.py": "from pkg.a import thing\n",
        "pkg/a.py": "thing = 1\n\ndef later():\n    from . import b\n    return b\n",
        "pkg/b.py": "import numpy\nfrom pkg import a\n",
        "other/__init__.py": "",
        "other/c.py": "from pkg.b import numpy\n",
        "smokeseer/__init__.py": "",
        "smokeseer/api.py": "",
        "smokeseer/train/stage3.py": "",
        "eval/__init__.py": "",
        "eval/harness.py": "from smokeseer.api import x\n\ndef f():\n    from smokeseer.train.stage3 import depth_term_on\n",
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    graph = import_graph(tmp_path)
    assert graph["other.c"] == {"pkg.b": 1, "pkg": 1}
    assert find_cycle(graph) == ["pkg.a", "pkg.b", "pkg.a"]
    assert internal_trainer_imports(graph) == ["eval.harness:4 imports smokeseer.train.stage3"]
    (tmp_path / "pkg" / "a.py").write_text("thing = 1\n")
    assert find_cycle(import_graph(tmp_path)) is None
