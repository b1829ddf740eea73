"""The project's own modules a task imports, and a digest of their code.

Why: a cached result is valid only while the code that produced it is unchanged. Hashing whole
packages reruns everything after a docstring edit and misses a fix in a module imported from
another package; this follows the imports (at module level or inside functions) through the
project's packages and hashes each module's syntax tree with docstrings left out (comments
never reach the tree), plus the non-Python files (kernels, presets) that ship in those packages.
"""
from __future__ import annotations

import ast
import hashlib
from dataclasses import dataclass
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[1]
PROJECT_PACKAGES: tuple[str, ...] = ("blender", "contracts", "eval", "generator", "interop", "smokeseer")
_DATA_SUFFIXES = (".cpp", ".cu", ".cuh", ".h", ".hpp", ".yaml", ".yml", ".json")


@dataclass(frozen=True)
class ModuleSource:
    """One project module: its dotted name, file, and whether it is a package's ``__init__``."""

    name: str
    path: Path
    is_package: bool


def find_module(name: str, root: Path = PROJECT_ROOT) -> ModuleSource | None:
    """Locate a project module in the source tree at ``root`` without importing it (``blender``
    needs bpy); None for anything outside the project."""
    if not name or name.split(".")[0] not in PROJECT_PACKAGES:
        return None
    base = Path(root, *name.split("."))
    if (base / "__init__.py").is_file():
        return ModuleSource(name, base / "__init__.py", True)
    if base.with_suffix(".py").is_file():
        return ModuleSource(name, base.with_suffix(".py"), False)
    return None


@dataclass(frozen=True)
class _Parsed:
    """What the digest needs from one module file: its import names and its fingerprint."""

    imports: frozenset[str]
    fingerprint: str


_PARSED: dict[tuple[str, bool, str], _Parsed] = {}


def _parse(module: ModuleSource) -> _Parsed:
    """Parse the module once per content and name (keyed by the bytes' SHA-256, so an edit is
    never served stale): a run's provenance, the generator's staging key and the harness all
    ask for overlapping closures in one process, and parsing plus dumping is most of the cost."""
    source = module.path.read_bytes()
    key = (module.name, module.is_package, hashlib.sha256(source).hexdigest())
    parsed = _PARSED.get(key)
    if parsed is None:
        tree = ast.parse(source, filename=str(module.path))
        imports = frozenset(_imported_names(tree, module))
        fingerprint = ast.dump(_strip_docstrings(tree), annotate_fields=False, include_attributes=False)
        parsed = _PARSED[key] = _Parsed(imports, fingerprint)
    return parsed


def imported_names(module: ModuleSource) -> set[str]:
    """Every dotted name the module's imports may refer to, wherever the import statement sits."""
    return set(_parse(module).imports)


def _imported_names(tree: ast.AST, module: ModuleSource) -> set[str]:
    package = module.name if module.is_package else module.name.rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1])
                prefix = f"{base}.{node.module}" if node.module else base
            else:
                prefix = node.module or ""
            names.add(prefix)
            names.update(f"{prefix}.{alias.name}" for alias in node.names)
    return names


def project_imports(module: ModuleSource, root: Path = PROJECT_ROOT) -> set[str]:
    """The project modules ``module`` imports, with each one's parent packages (Python runs
    every parent ``__init__`` on import)."""
    found: set[str] = set()
    for name in imported_names(module):
        parts = name.split(".")
        for i in range(1, len(parts) + 1):
            candidate = ".".join(parts[:i])
            if candidate not in found and find_module(candidate, root) is not None:
                found.add(candidate)
    return found


def module_closure(*roots: str, root: Path = PROJECT_ROOT) -> list[ModuleSource]:
    """The root modules and every project module they import, transitively, sorted by name."""
    seen: dict[str, ModuleSource] = {}
    todo = list(roots)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        module = find_module(name, root)
        if module is None:
            raise ValueError(f"source digest: no project module named {name!r}")
        seen[name] = module
        parts = name.split(".")
        todo.extend(".".join(parts[:i]) for i in range(1, len(parts)))
        todo.extend(project_imports(module, root) - seen.keys())
    return [seen[k] for k in sorted(seen)]


def _strip_docstrings(tree: ast.AST) -> ast.AST:
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return tree


def code_fingerprint(path: Path) -> str:
    """The module's syntax tree without docstrings, as text: comments and layout do not count."""
    return _parse(ModuleSource("", Path(path), False)).fingerprint


def _package_data(module: ModuleSource) -> list[Path]:
    """Non-Python files that ship with a package (kernel sources, presets), below its folder but
    outside its sub-packages."""
    root = module.path.parent
    files = []
    for f in sorted(root.rglob("*")):
        if not f.is_file() or f.suffix not in _DATA_SUFFIXES or "__pycache__" in f.parts:
            continue
        inner = f.parent
        while inner != root and not (inner / "__init__.py").is_file():
            inner = inner.parent
        if inner == root:
            files.append(f)
    return files


def code_digest(*roots: str, root: Path = PROJECT_ROOT) -> str:
    """SHA-256 of the code of ``roots`` and everything of the project they import."""
    h = hashlib.sha256()
    for module in module_closure(*roots, root=root):
        h.update(f"{module.name}\0{_parse(module).fingerprint}\0".encode())
        if module.is_package:
            for f in _package_data(module):
                h.update(f"{module.name}/{f.relative_to(module.path.parent).as_posix()}\0".encode())
                h.update(f.read_bytes())
    return h.hexdigest()
