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
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[1]
PROJECT_PACKAGES: tuple[str, ...] = ("blender", "contracts", "eval", "generator", "interop", "scenes", "smokeseer")
_DATA_SUFFIXES = (".cpp", ".cu", ".cuh", ".h", ".hpp", ".yaml", ".yml", ".json")
DIGEST_CACHE_ENV = "SMOKESEER_DIGEST_CACHE"
"""File of remembered digests; set to an empty string to turn the cache off."""
_CACHE_ENTRIES = 64


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


def import_statements(tree: ast.AST, package: str) -> list[tuple[str, int]]:
    """Every dotted name an import statement of ``tree`` may refer to, with its line, wherever the
    statement sits; relative imports resolve against ``package`` (the module's own for a package)."""
    found: list[tuple[str, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1])
                prefix = f"{base}.{node.module}" if node.module else base
            else:
                prefix = node.module or ""
            found.append((prefix, node.lineno))
            found += [(f"{prefix}.{alias.name}", node.lineno) for alias in node.names]
    return found


def _imported_names(tree: ast.AST, module: ModuleSource) -> set[str]:
    package = module.name if module.is_package else module.name.rpartition(".")[0]
    return {name for name, _ in import_statements(tree, package)}


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


def package_data(module: ModuleSource) -> list[Path]:
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


def _computed_digest(*roots: str, root: Path = PROJECT_ROOT) -> str:
    """The digest itself: each closure module's name and fingerprint, and its package data."""
    h = hashlib.sha256()
    for module in module_closure(*roots, root=root):
        h.update(f"{module.name}\0{_parse(module).fingerprint}\0".encode())
        if module.is_package:
            for f in package_data(module):
                h.update(f"{module.name}/{f.relative_to(module.path.parent).as_posix()}\0".encode())
                h.update(f.read_bytes())
    return h.hexdigest()


def digest_cache_path() -> Path | None:
    """``$SMOKESEER_DIGEST_CACHE`` (empty: no cache), else ``$XDG_CACHE_HOME`` or ``~/.cache``
    ``/smokeseer/source_digests.json``."""
    env = os.environ.get(DIGEST_CACHE_ENV)
    if env is not None:
        return Path(env) if env else None
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "smokeseer" / "source_digests.json"


def _tree_key(roots: tuple[str, ...], root: Path) -> str:
    """SHA-256 of the entry points and of every file the digest could read (each project
    package's Python and data files, by relative path and bytes): the digest is a function of
    these alone, so an equal key means an equal digest. Hashing them takes ~6 ms."""
    h = hashlib.sha256("\0".join(roots).encode() + b"\1")
    for package in PROJECT_PACKAGES:
        base = Path(root, package)
        for f in sorted(base.rglob("*")) if base.is_dir() else ():
            if f.suffix in (".py", *_DATA_SUFFIXES) and "__pycache__" not in f.parts and f.is_file():
                h.update(f"{f.relative_to(root).as_posix()}\0".encode() + f.read_bytes() + b"\0")
    return h.hexdigest()


def _read_cache(path: Path) -> dict[str, str]:
    try:
        entries = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return entries if isinstance(entries, dict) else {}


def _write_cache(path: Path, entries: dict[str, str]) -> None:
    """Best effort (a read-only home only costs the recomputation), through a uniquely named
    temporary file and a rename, so concurrent runs never read a half-written cache."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, prefix=f".{path.name}.", delete=False) as tmp:
            json.dump(entries, tmp)
        os.replace(tmp.name, path)
    except OSError:
        pass


def code_digest(*roots: str, root: Path = PROJECT_ROOT) -> str:
    """SHA-256 of the code of ``roots`` and everything of the project they import.

    Remembered on disk by ``_tree_key`` (``digest_cache_path``): parsing and dumping the ~40
    modules of the trainer's closure takes 0.2-0.9 s of every run, hashing the files 6 ms."""
    path = digest_cache_path()
    if path is None:
        return _computed_digest(*roots, root=root)
    key = _tree_key(roots, Path(root))
    entries = _read_cache(path)
    digest = entries.get(key)
    if not isinstance(digest, str):
        digest = _computed_digest(*roots, root=root)
        entries.pop(key, None)
        entries[key] = digest
        _write_cache(path, dict(list(entries.items())[-_CACHE_ENTRIES:]))
    return digest
