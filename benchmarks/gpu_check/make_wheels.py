"""``python -m benchmarks.gpu_check.make_wheels --python 3.12 --out DIR``: the wheel folder for a
GPU node without internet, made on a machine with it.

pip resolves the folder's requirements (wheels.folder_requirements) for the target's Python and
platform into a staging folder; what the GPU image has (wheels.excluded) is then dropped, gsplat's
source archive is added, and the result is checked (wheels.check_folder) and described in
manifest.json. Nothing is written to --out unless the check passes.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from packaging.requirements import Requirement
from packaging.tags import Tag, compatible_tags, cpython_tags
from packaging.utils import canonicalize_name

from benchmarks.gpu_check.wheels import (GSPLAT, check_folder, excluded, folder_requirements, missing_in_closure,
                                        read_folder)

ROOT = Path(__file__).resolve().parents[2]
MARKER_ROUNDS = 3


def platform_tags(glibc_minor: int) -> list[str]:
    """The manylinux tags an x86-64 Linux with glibc 2.``glibc_minor`` accepts (and the legacy aliases)."""
    tags = [f"manylinux_2_{m}_x86_64" for m in range(glibc_minor, 4, -1)]
    return tags + ["manylinux2014_x86_64", "manylinux2010_x86_64", "manylinux1_x86_64"]


def interpreter_tags(python: str, glibc_minor: int) -> list[Tag]:
    """The wheel tags a CPython ``python`` on that Linux accepts, as pip's --python-version would."""
    version = tuple(int(x) for x in python.split("."))
    plats = platform_tags(glibc_minor)
    return [*cpython_tags(version, platforms=plats), *compatible_tags(version, f"cp{version[0]}{version[1]}", plats)]


def pip(*args: str, env: dict[str, str] | None = None) -> None:
    """Run pip of this interpreter; its last lines become the error on failure."""
    res = subprocess.run([sys.executable, "-m", "pip", *args], capture_output=True, text=True, env=env)
    if res.returncode != 0:
        tail = "\n".join((res.stdout + res.stderr).strip().splitlines()[-8:])
        raise RuntimeError(f"pip {args[0]} failed:\n{tail}")


def make_folder(out: Path, python: str, glibc_minor: int) -> dict:
    """Download, filter, check and describe the folder; returns the manifest."""
    pyproject = ROOT / "pyproject.toml"
    reqs = [str(r) for r in folder_requirements(pyproject)]
    with tempfile.TemporaryDirectory() as tmp:
        stage = Path(tmp) / "stage"
        plat = [a for t in platform_tags(glibc_minor) for a in ("--platform", t)]
        wanted = reqs
        # pip evaluates the markers of dependencies for the Python it runs on, not --python-version's:
        # what only an older or newer Python needs (tomli below 3.11, say) is fetched in later rounds.
        for _ in range(MARKER_ROUNDS):
            pip("download", "--quiet", "--only-binary=:all:", "--implementation", "cp", "--python-version", python,
                *plat, "--dest", str(stage), *wanted)
            missing = missing_in_closure(read_folder(stage)[0], folder_requirements(pyproject), python)
            wanted = sorted({str(Requirement(f"{r.name}{r.specifier}")) for r, _ in missing})
            if not wanted:
                break
        # BUILD_NO_CUDA: gsplat's setup.py describes its CUDA extension only when asked to build it;
        # reading the archive's metadata here needs no CUDA.
        pip("download", "--quiet", "--no-deps", "--no-binary=:all:", "--dest", str(stage), str(GSPLAT),
            env={**os.environ, "BUILD_NO_CUDA": "1"})
        artifacts, _ = read_folder(stage)
        keep = Path(tmp) / "folder"
        keep.mkdir()
        dropped = []
        for a in artifacts:
            if a.name in excluded():
                dropped.append(a.path.name)
            else:
                shutil.copy2(a.path, keep / a.path.name)
        check = check_folder(keep, pyproject, python, interpreter_tags(python, glibc_minor))
        if not check.ok:
            raise RuntimeError("the folder is incomplete:\n" + "\n".join(check.problems))
        manifest = {"python": python, "glibc": f"2.{glibc_minor}", "requirements": reqs,
                    "gsplat": str(GSPLAT), "excluded": sorted(excluded()), "left_out": sorted(dropped),
                    "size_bytes": check.size_bytes,
                    "files": {p.name: p.stat().st_size for p in sorted(keep.iterdir())}}
        (keep / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
        if out.exists():
            shutil.rmtree(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copytree(keep, out)
    return manifest


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="make_wheels", description=__doc__.splitlines()[0])
    p.add_argument("--python", required=True, help="the GPU node's Python, e.g. 3.12 (python3 --version there)")
    p.add_argument("--out", type=Path, required=True, help="the folder to write (replaced if it exists)")
    p.add_argument("--glibc", default="2.28", help="the node's glibc (ldd --version there; default 2.28)")
    args = p.parse_args(argv)
    try:
        major, minor = (int(x) for x in args.python.split("."))
        glibc_minor = int(args.glibc.split(".")[1])
        if major != 3 or args.glibc.split(".")[0] != "2":
            raise ValueError
    except ValueError:
        print(f"make_wheels: error: --python wants 3.N and --glibc 2.N, got {args.python!r} and {args.glibc!r}",
              file=sys.stderr)
        return 2
    try:
        manifest = make_folder(args.out, f"{major}.{minor}", glibc_minor)
    except (RuntimeError, ValueError) as exc:
        print(f"make_wheels: error: {exc}", file=sys.stderr)
        return 1
    print(f"{args.out}: {len(manifest['files'])} files, {manifest['size_bytes'] / 1e6:.1f} MB for Python "
          f"{manifest['python']} (left out: {', '.join(sorted({canonicalize_name(n.split('-')[0]) for n in manifest['left_out']}))})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
