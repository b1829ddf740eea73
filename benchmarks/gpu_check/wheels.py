"""What the wheel folder must hold, and whether a folder holds it.

A GPU node without internet gets the project's runtime dependencies as files. Its image already
has torch, numpy, scipy and matplotlib, and therefore everything those require (their declared
dependencies), so those are left out; bpy and miepython are left out because training never
imports them (they make datasets), and so is pycolmap (poses for captures that have none). gsplat
travels as its source archive, because its CUDA code is compiled for the GPU and CUDA found there.
"""
from __future__ import annotations

import tomllib
import zipfile
from dataclasses import dataclass, field
from email.parser import HeaderParser
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.tags import Tag, parse_tag
from packaging.utils import (InvalidSdistFilename, InvalidWheelFilename, NormalizedName, canonicalize_name,
                             parse_sdist_filename, parse_wheel_filename)

from benchmarks.gpu_check.prebuilt import RECORD as PREBUILT_RECORD

GSPLAT = Requirement("gsplat==1.5.3")
"""The gsplat release the adapter (smokeseer/raster/gsplat_backend.py) is checked against."""
GSPLAT_RUNTIME = ("jaxtyping", "rich>=12")
"""gsplat's own requirements that no GPU image is assumed to have (its others: torch, numpy, ninja)."""
BUILD_REQUIREMENTS = ("setuptools>=68", "wheel")
"""The project's build-system requirements: pip builds the project from source offline with them."""
IMAGE_PACKAGES = ("torch", "numpy", "scipy", "matplotlib")
"""Installed on the GPU image, with the CUDA build of torch that matches its driver."""
IMAGE_PROVIDES = ("contourpy", "cycler", "filelock", "fonttools", "fsspec", "jinja2", "kiwisolver", "markupsafe",
                  "mpmath", "networkx", "packaging", "pillow", "pyparsing", "python-dateutil", "sympy",
                  "typing-extensions")
"""Requirements of IMAGE_PACKAGES (torch 2.x and matplotlib 3.x declare them), so present with them."""
NOT_FOR_TRAINING = ("bpy", "miepython", "pycolmap")
"""Not imported when a posed dataset trains: Blender (about 1 GB) and the Mie optics (miepython
pulls numba and llvmlite, about 64 MB) make datasets; structure from motion (pycolmap, 38 MB) runs
only for captures without poses."""
FOLDER_LIMIT_BYTES = 60 * 10**6


def excluded() -> frozenset[NormalizedName]:
    """Distribution names the wheel folder leaves out."""
    return frozenset(canonicalize_name(n) for n in (*IMAGE_PACKAGES, *IMAGE_PROVIDES, *NOT_FOR_TRAINING))


def project_requirements(pyproject: Path) -> list[Requirement]:
    """The project's runtime and test requirements, read from pyproject.toml."""
    try:
        project = tomllib.loads(pyproject.read_text())["project"]
        listed = [*project["dependencies"], *project["optional-dependencies"]["test"]]
    except (OSError, tomllib.TOMLDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{pyproject}: cannot read [project] dependencies and the 'test' extra ({exc})") from None
    return [Requirement(r) for r in listed]


def folder_requirements(pyproject: Path) -> list[Requirement]:
    """What the folder must satisfy: the project's requirements less the excluded names, gsplat's
    runtime requirements and the project's build requirements. gsplat itself is checked apart
    (it must come as a source archive)."""
    drop = excluded()
    wanted = [r for r in project_requirements(pyproject) if canonicalize_name(r.name) not in drop]
    return wanted + [Requirement(r) for r in (*GSPLAT_RUNTIME, *BUILD_REQUIREMENTS)]


@dataclass(frozen=True)
class Artifact:
    """One file of the folder, by the name and version its file name carries."""

    path: Path
    name: NormalizedName
    version: str
    tags: frozenset[Tag] = field(default_factory=frozenset)  # empty for a source archive

    @property
    def is_sdist(self) -> bool:
        return not self.tags


def read_folder(folder: Path) -> tuple[list[Artifact], list[str]]:
    """The folder's wheels and source archives, and the names of files that are neither."""
    found, strays = [], []
    for path in sorted(p for p in folder.iterdir() if p.is_file()):
        try:
            if path.name.endswith(".whl"):
                name, version, _, tags = parse_wheel_filename(path.name)
                found.append(Artifact(path, name, str(version), frozenset(tags)))
            elif path.name.endswith(".tar.gz"):
                name, version = parse_sdist_filename(path.name)
                found.append(Artifact(path, name, str(version)))
            elif path.name not in ("manifest.json", PREBUILT_RECORD):
                strays.append(path.name)
        except (InvalidWheelFilename, InvalidSdistFilename):
            strays.append(path.name)
    return found, strays


@dataclass
class FolderCheck:
    """Problems found in a wheel folder, one line each (empty: complete)."""

    problems: list[str]
    size_bytes: int
    files: int

    @property
    def ok(self) -> bool:
        return not self.problems


def check_folder(folder: Path, pyproject: Path, python: str, supported: list[Tag] | None = None) -> FolderCheck:
    """Every requirement has a file of a matching version (a wheel for ``supported`` tags when
    given, e.g. the running interpreter's), so does every requirement of those wheels under Python
    ``python`` (e.g. "3.12") unless the image has it, gsplat is there as its source archive, no excluded
    package slipped in, and the folder is under FOLDER_LIMIT_BYTES."""
    if not folder.is_dir():
        return FolderCheck([f"{folder}: not a directory"], 0, 0)
    artifacts, strays = read_folder(folder)
    problems = [f"{folder / s}: not a wheel or source archive" for s in strays]
    accept = frozenset(supported) if supported is not None else None
    for req in folder_requirements(pyproject):
        name = canonicalize_name(req.name)
        candidates = [a for a in artifacts if a.name == name and not a.is_sdist]
        matching = [a for a in candidates if req.specifier.contains(a.version, prereleases=True)]
        usable = [a for a in matching if accept is None or a.tags & accept]
        if not candidates:
            problems.append(f"{folder}: no wheel for {req}")
        elif not matching:
            problems.append(f"{folder}: {req} wanted, found {', '.join(a.path.name for a in candidates)}")
        elif not usable:
            problems.append(f"{folder}: no wheel of {req} for this Python and platform "
                            f"(found {', '.join(a.path.name for a in matching)})")
    gsplat = [a for a in artifacts if a.name == canonicalize_name(GSPLAT.name)]
    if not any(a.is_sdist and GSPLAT.specifier.contains(a.version) for a in gsplat):
        problems.append(f"{folder}: no source archive of {GSPLAT} (gsplat-{GSPLAT.specifier}.tar.gz)")
    if not problems:
        problems += unmet_in_closure(artifacts, folder_requirements(pyproject), python)
    problems += [f"{a.path}: {a.name} is left out of the folder (the GPU image has it, or training does not use it)"
                 for a in artifacts if a.name in excluded()]
    size = sum(a.path.stat().st_size for a in artifacts)
    if size >= FOLDER_LIMIT_BYTES:
        problems.append(f"{folder}: {size / 1e6:.1f} MB, over the {FOLDER_LIMIT_BYTES / 1e6:.0f} MB limit")
    return FolderCheck(problems, size, len(artifacts))


def tags_from_strings(tags: list[str]) -> list[Tag]:
    """Tags such as ``cp312-cp312-manylinux_2_17_x86_64`` (compressed sets allowed)."""
    return [t for s in tags for t in parse_tag(s)]


def wheel_requirements(path: Path) -> list[Requirement]:
    """The Requires-Dist lines of a wheel's METADATA."""
    try:
        with zipfile.ZipFile(path) as z:
            meta = next(n for n in z.namelist() if n.count("/") == 1 and n.endswith(".dist-info/METADATA"))
            headers = HeaderParser().parsestr(z.read(meta).decode("utf-8"))
    except (OSError, zipfile.BadZipFile, StopIteration, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: unreadable wheel ({type(exc).__name__})") from None
    return [Requirement(r) for r in headers.get_all("Requires-Dist") or []]


def unmet_in_closure(artifacts: list[Artifact], top: list[Requirement], python: str) -> list[str]:
    """One line per requirement of the closure (missing_in_closure) that nothing satisfies."""
    return list(dict.fromkeys(line for _, line in missing_in_closure(artifacts, top, python)))


def missing_in_closure(artifacts: list[Artifact], top: list[Requirement],
                       python: str) -> list[tuple[Requirement, str]]:
    """Walk the requirements from ``top`` through the folder's wheels (markers evaluated for a
    Linux x86-64 CPython ``python``, extras followed); each one neither the folder nor the image
    satisfies, with a line that says who wants it."""
    env = {**default_environment(), "python_version": python, "python_full_version": f"{python}.0",
           "sys_platform": "linux", "platform_system": "Linux", "platform_machine": "x86_64",
           "implementation_name": "cpython", "platform_python_implementation": "CPython", "os_name": "posix"}
    wheels = {a.name: a for a in artifacts if not a.is_sdist}
    image = excluded()
    problems: list[tuple[Requirement, str]] = []
    seen: set[tuple[str, str]] = set()
    todo = [(r, "pyproject.toml") for r in top]
    while todo:
        req, wanted_by = todo.pop()
        name = canonicalize_name(req.name)
        if name in image:
            continue
        have = wheels.get(name)
        if have is None or not req.specifier.contains(have.version, prereleases=True):
            problems.append((req, f"{req} (wanted by {wanted_by}): "
                                  f"{'not in the folder' if have is None else 'the folder has ' + have.version}"))
            continue
        for extra in ("", *sorted(req.extras)):
            if (name, extra) in seen:
                continue
            seen.add((name, extra))
            try:
                reqs = wheel_requirements(have.path)
            except ValueError as exc:
                problems.append((req, str(exc)))
                break
            for sub in reqs:
                if sub.marker is None and extra:
                    continue  # taken with the extra-less pass
                if sub.marker is None or sub.marker.evaluate({**env, "extra": extra}):
                    todo.append((sub, f"{have.name} {have.version}"))
    return problems
