"""``python -m benchmarks.gpu_check.prebuild_gsplat --wheels DIR --arch 9.0``: compile gsplat's
source archive in the wheel folder into a wheel for one kind of GPU node, and record what it was
built for (benchmarks.gpu_check.prebuilt).

Run it with an interpreter whose Python minor version and torch (with its CUDA) are the node's, on
a machine with the matching CUDA toolkit (nvcc); no GPU is needed. The GPU check then installs the
wheel instead of compiling on the node. Nothing is written unless the build succeeds.
"""
from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.gpu_check.prebuilt import RECORD, PrebuiltRecord
from benchmarks.gpu_check.target import cpu_jobs, memory_gib, nvcc_version
from benchmarks.gpu_check.wheels import GSPLAT, read_folder
from contracts.atomic import write_json


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="prebuild_gsplat", description=__doc__.splitlines()[0])
    p.add_argument("--wheels", type=Path, required=True, help="the folder make_wheels wrote (holds gsplat's archive)")
    p.add_argument("--arch", required=True, help="TORCH_CUDA_ARCH_LIST of the node's GPU, e.g. 9.0 for an H100")
    args = p.parse_args(argv)
    try:
        import torch
        from torch.utils.cpp_extension import CUDA_HOME
    except ImportError as exc:
        print(f"prebuild_gsplat: error: torch: {exc}", file=sys.stderr)
        return 2
    archive = [a.path for a in read_folder(args.wheels)[0] if a.is_sdist and a.name == GSPLAT.name] \
        if args.wheels.is_dir() else []
    nvcc = shutil.which("nvcc", path=str(Path(CUDA_HOME) / "bin")) if CUDA_HOME else None
    headers = bool(CUDA_HOME) and (Path(CUDA_HOME) / "include" / "cuda_runtime.h").is_file()
    problems = [msg for bad, msg in (
        (not archive, f"--wheels: {args.wheels} holds no source archive of {GSPLAT}"),
        (torch.version.cuda is None, f"torch {torch.__version__} is a CPU build: no CUDA to compile against"),
        (nvcc is None or not headers, f"CUDA_HOME ({CUDA_HOME}) has no bin/nvcc and include/cuda_runtime.h; "
                                      f"set CUDA_HOME to the toolkit of CUDA {torch.version.cuda}"),
    ) if bad]
    if problems:
        print(f"prebuild_gsplat: error: {problems[0]}", file=sys.stderr)
        return 2
    nvcc_release = nvcc_version(subprocess.run([nvcc, "--version"], capture_output=True, text=True).stdout)
    jobs = cpu_jobs(os.cpu_count() or 1, memory_gib())
    env = {**os.environ, "TORCH_CUDA_ARCH_LIST": args.arch, "MAX_JOBS": str(jobs), "CUDA_HOME": CUDA_HOME}
    with tempfile.TemporaryDirectory() as tmp:
        start = time.monotonic()
        res = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-cache-dir", "--no-index", "--no-deps",
                              "--no-build-isolation", "--wheel-dir", tmp, str(archive[0])],
                             env=env, capture_output=True, text=True)
        seconds = time.monotonic() - start
        built = sorted(Path(tmp).glob("gsplat-*.whl"))
        if res.returncode != 0 or not built:
            tail = "\n".join((res.stdout + res.stderr).strip().splitlines()[-15:])
            print(f"prebuild_gsplat: error: the build failed after {seconds:.0f} s:\n{tail}", file=sys.stderr)
            return 1
        for old in args.wheels.glob("gsplat-*.whl"):
            old.unlink()
        shutil.copy2(built[0], args.wheels / built[0].name)
    record = PrebuiltRecord(wheel=built[0].name, python=".".join(platform.python_version().split(".")[:2]),
                            torch=torch.__version__, torch_cuda=str(torch.version.cuda), arch_list=args.arch,
                            nvcc=str(nvcc_release), seconds=round(seconds, 1), jobs=jobs, cpus=os.cpu_count() or 1)
    write_json(args.wheels / RECORD, record.to_dict())
    size = (args.wheels / record.wheel).stat().st_size
    print(f"{args.wheels / record.wheel}: {size / 1e6:.1f} MB, compiled in {seconds:.0f} s with {jobs} jobs for "
          f"arch {args.arch}, Python {record.python}, torch {record.torch} (CUDA {record.torch_cuda})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
