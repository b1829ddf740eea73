"""Builds (once) and loads compiled CPU kernels with torch.utils.cpp_extension: the tile
rasterizer (``TILE_RASTER``), and any other ``Kernel`` (the plane field's lookups,
``smokeseer.model.planes.PLANE_FEATURES``).

The build directory is keyed by a hash of the source, the flags and the torch installation it
links against, so an edited kernel is rebuilt, an unchanged one loads in milliseconds, and two
virtual environments keep one build each instead of rebuilding it whenever the other one loads
it (ninja's command line holds the environment's torch include and library paths). The sources are copied into that directory
and compiled from there: ninja's command line then holds no checkout path, so two checkouts of
the same kernel share one build instead of rebuilding it each time the other one loads it. A
failed build raises ``KernelBuildError`` with the compiler's own complaint; nothing falls back
to the slower torch code.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from contracts.float_setup import kernel_vector_flags

CSRC = Path(__file__).resolve().parent / "csrc"


@dataclass(frozen=True)
class Kernel:
    """One compiled module: its name prefix, what it is (for messages), its sources and headers,
    and what to do when it cannot be built."""

    name: str
    what: str
    sources: tuple[Path, ...]
    headers: tuple[Path, ...]
    remedy: str


TILE_RASTER = Kernel("smokeseer_tile_raster", "the CPU tile rasterizer",
                     (CSRC / "tile_raster.cpp", CSRC / "projection.cpp", CSRC / "sh_colors.cpp"),
                     (CSRC / "projection.h", CSRC / "sh_colors.h"),
                     "or pass backend='torch' explicitly to use the slow reference backend")
# -ffp-contract=off: forward and backward recompute alpha with the same rounding (no FMA fusion
# that could differ between the two call sites), so both passes agree on which pairs are skipped.
# -fno-math-errno: sqrt/ceil inline as single instructions (the kernel never reads errno).
BASE_CFLAGS = ["-O3", "-fopenmp", "-ffp-contract=off", "-fno-math-errno"]
LDFLAGS = ["-fopenmp"]


def compiler_flags() -> list[str]:
    """Base flags, plus AVX2/FMA (8-wide float loops) when this machine's CPU has them
    (``contracts.float_setup.kernel_vector_flags``: never -march=native, so a build cache copied to an
    older CPU of the same family still runs, and AVX2 and AVX-512 machines build the same kernel; the
    cache key holds the flags)."""
    return BASE_CFLAGS + kernel_vector_flags()


_lock = threading.Lock()
_modules: dict[str, ModuleType] = {}


class KernelBuildError(RuntimeError):
    """A compiled CPU kernel could not be compiled or loaded."""


def build_directory(kernel: Kernel = TILE_RASTER) -> tuple[Path, str]:
    """Per-source-hash cache folder and module name under torch's extensions root
    (``TORCH_EXTENSIONS_DIR`` when set, else ~/.cache/torch_extensions)."""
    import torch
    from torch.utils.cpp_extension import get_default_build_root

    torch_install = f"{torch.__version__} {Path(torch.__file__).resolve().parent}"
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in kernel.sources + kernel.headers)
                            + " ".join(compiler_flags() + LDFLAGS).encode()
                            + torch_install.encode()).hexdigest()[:12]
    name = f"{kernel.name}_{digest}"
    root = Path(os.environ.get("TORCH_EXTENSIONS_DIR") or get_default_build_root())
    folder = root / name
    folder.mkdir(parents=True, exist_ok=True)
    return folder, name


def staged_sources(folder: Path, kernel: Kernel = TILE_RASTER) -> list[Path]:
    """The kernel's sources copied into ``folder`` (only where missing or different; each through
    a uniquely named temporary file and a rename, so processes staging at once never see a
    half-written source); returns the copied .cpp paths to compile."""
    for src in kernel.sources + kernel.headers:
        dst = folder / src.name
        data = src.read_bytes()
        if dst.is_file() and dst.read_bytes() == data:
            continue
        with tempfile.NamedTemporaryFile(dir=folder, prefix=f".{src.name}.", delete=False) as tmp:
            tmp.write(data)
        os.replace(tmp.name, dst)
    return [folder / p.name for p in kernel.sources]


def _compiler_summary(err: BaseException) -> str:
    text = str(err).strip()
    lines = [ln for ln in text.splitlines() if "error" in ln.lower()] or text.splitlines()[-3:]
    return " | ".join(ln.strip() for ln in lines[:4])


def load_kernel(kernel: Kernel = TILE_RASTER) -> ModuleType:
    """The compiled module; compiles it on first use and prints the compile time once."""
    with _lock:
        if kernel.name in _modules:
            return _modules[kernel.name]
        from torch.utils import cpp_extension

        folder, name = build_directory(kernel)
        fresh = not any(folder.glob(f"{name}*.so"))
        if fresh:
            print(f"smokeseer: compiling {kernel.what} into {folder} (first use) ...", file=sys.stderr, flush=True)
        start = time.perf_counter()
        try:
            module = cpp_extension.load(
                name=name, sources=[str(p) for p in staged_sources(folder, kernel)], extra_cflags=compiler_flags(),
                extra_ldflags=LDFLAGS,
                build_directory=str(folder), verbose=False,
            )
        except (RuntimeError, OSError, ImportError, subprocess.CalledProcessError) as err:
            compiler = os.environ.get("CXX", "c++")
            raise KernelBuildError(
                f"could not build {kernel.what} {kernel.sources[0].parent} with compiler {compiler!r}: "
                f"{_compiler_summary(err)}. Install g++ (and ninja: pip install ninja), {kernel.remedy}."
            ) from None
        if fresh:
            print(f"smokeseer: compiled {kernel.what} in {time.perf_counter() - start:.1f} s (cached for later runs)",
                  file=sys.stderr, flush=True)
        _modules[kernel.name] = module
        return module
