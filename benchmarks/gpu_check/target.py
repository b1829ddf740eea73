"""What the GPU node is: Python, torch, CUDA (torch's and nvcc's), the GPU and its compute
capability, the build tools. ``python -m benchmarks.gpu_check.target`` prints it as JSON (run in
a child process, so the check itself never holds a CUDA context)."""
from __future__ import annotations

import json
import os
import platform
import re
import shutil
import subprocess
import sys
from typing import Any

NVCC_RELEASE = re.compile(r"release (\d+)\.(\d+)")


def nvcc_version(text: str) -> str | None:
    """``12.4`` from the output of ``nvcc --version`` (None when it names no release)."""
    m = NVCC_RELEASE.search(text)
    return f"{m.group(1)}.{m.group(2)}" if m else None


def arch_list(capabilities: list[tuple[int, int]]) -> str:
    """TORCH_CUDA_ARCH_LIST for the GPUs present, e.g. ``9.0`` for an H100, so nvcc compiles for
    them alone (each extra architecture adds a full compile of every kernel)."""
    if not capabilities:
        raise ValueError("no CUDA device: no architecture to compile for")
    return ";".join(f"{major}.{minor}" for major, minor in sorted(set(capabilities)))


def cpu_jobs(cpus: int, memory_gib: float | None) -> int:
    """Parallel compile jobs: one per core, but at most one per 2.5 GiB of memory (an nvcc job
    of gsplat's larger kernels takes about 2 GiB)."""
    jobs = max(cpus, 1)
    if memory_gib is not None:
        jobs = min(jobs, max(int(memory_gib / 2.5), 1))
    return jobs


def memory_gib() -> float | None:
    """Physical memory from /proc/meminfo (None elsewhere)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal:"):
                    return int(line.split()[1]) / 2**20
    except OSError:
        return None
    return None


def _tool(argv: list[str]) -> str | None:
    if shutil.which(argv[0]) is None:
        return None
    res = subprocess.run(argv, capture_output=True, text=True)
    return (res.stdout + res.stderr).strip() or None


def probe() -> dict[str, Any]:
    """Everything the report states about the node, collected in this process."""
    info: dict[str, Any] = {"python": platform.python_version(), "executable": sys.executable,
                            "platform": platform.platform(), "cpus": os.cpu_count() or 1, "memory_gib": memory_gib()}
    try:
        import torch
    except ImportError as exc:
        info["torch"] = None
        info["torch_error"] = str(exc)
        return info
    info["torch"] = torch.__version__
    info["torch_cuda"] = torch.version.cuda
    info["cuda_available"] = torch.cuda.is_available()
    devices = range(torch.cuda.device_count()) if info["cuda_available"] else range(0)
    info["gpus"] = [torch.cuda.get_device_name(i) for i in devices]
    caps = [torch.cuda.get_device_capability(i) for i in devices]
    info["capabilities"] = [f"{a}.{b}" for a, b in caps]
    info["arch_list"] = arch_list(caps) if caps else None
    info["gpu_memory_gib"] = [torch.cuda.get_device_properties(i).total_memory / 2**30 for i in devices]
    from torch.utils.cpp_extension import CUDA_HOME  # where torch's extension builds look for CUDA

    info["cuda_home"] = CUDA_HOME
    info["cuda_headers"] = bool(CUDA_HOME) and os.path.isfile(os.path.join(CUDA_HOME, "include", "cuda_runtime.h"))
    nvcc = _tool(["nvcc", "--version"])
    info["nvcc"] = nvcc_version(nvcc) if nvcc else None
    info["ninja"] = _tool(["ninja", "--version"])
    info["compile_jobs"] = cpu_jobs(info["cpus"], info["memory_gib"])
    return info


if __name__ == "__main__":
    print(json.dumps(probe()))
