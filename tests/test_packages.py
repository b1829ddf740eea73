"""Package structure: data flows one way (spec -> Blender worker -> dataset -> trainer -> run
folder -> tables), so no package may import a package that imports it back, at module level
or inside a function."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from contracts.source import PROJECT_PACKAGES, ModuleSource, find_module, imported_names

ROOT = Path(__file__).resolve().parents[1]


def _modules() -> list[ModuleSource]:
    out = []
    for top in PROJECT_PACKAGES:
        for f in sorted((ROOT / top).rglob("*.py")) if (ROOT / top).is_dir() else []:
            rel = f.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            is_package = parts[-1] == "__init__"
            if is_package:
                parts = parts[:-1]
            out.append(ModuleSource(".".join(parts), f, is_package))
    return out


def _package_of(name: str) -> str:
    """The package a module lives in (a package's ``__init__`` belongs to the package itself)."""
    module = find_module(name)
    if module is None:
        raise KeyError(name)
    return name if module.is_package else name.rpartition(".")[0]


def _target(name: str) -> str | None:
    """The deepest project module a dotted import name refers to."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        if find_module(".".join(parts[:i])) is not None:
            return ".".join(parts[:i])
    return None


def package_graph() -> dict[str, dict[str, str]]:
    """package -> {imported package: the first module that imports it}."""
    graph: dict[str, dict[str, str]] = {}
    for module in _modules():
        src = module.name if module.is_package else module.name.rpartition(".")[0]
        for name in imported_names(module):
            target = _target(name)
            if target is None:
                continue
            dst = _package_of(target)
            if dst != src:
                graph.setdefault(src, {}).setdefault(dst, module.name)
    return graph


def find_cycle(graph: dict[str, dict[str, Any]]) -> list[str] | None:
    """One cycle of a graph (node -> {neighbour: anything}) as [a, b, ..., a], or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, {})):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def test_no_package_imports_a_package_that_imports_it_back() -> None:
    graph = package_graph()
    cycle = find_cycle(graph)
    detail = "" if cycle is None else " -> ".join(
        f"{a} ({graph[a][b]} imports {b})" for a, b in zip(cycle, cycle[1:]))
    assert cycle is None, f"import cycle between packages: {detail}"


def test_trainer_and_harness_meet_only_through_contracts() -> None:
    graph = package_graph()
    assert not any(dst.split(".")[0] == "eval" for dst in graph.get("smokeseer", {}))
    assert not any(dst.split(".")[0] in ("smokeseer", "eval", "generator", "blender", "interop")
                   for src, deps in graph.items() if src.split(".")[0] == "contracts" for dst in deps)


def test_cycle_finder_sees_an_import_inside_a_function(tmp_path: Path) -> None:
    """The checker itself: a lazy import back is a cycle too."""
    graph = {"a": {"b": "a.x"}, "b": {"a": "b.y (inside a function)"}, "c": {"a": "c.z"}}
    assert find_cycle(graph) == ["a", "b", "a"]
    assert find_cycle({"a": {"b": "a.x"}, "c": {"a": "c.z"}}) is None
    lazy = tmp_path / "m.py"
    lazy.write_text("def f():\n    from eval.harness import regenerate\n")
    assert "eval.harness" in imported_names(ModuleSource("smokeseer.m", lazy, False))
