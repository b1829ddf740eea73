"""What sets a run's float rounding on this machine, for its provenance and its harness record.

The same settings, data, code and seed train to the same bytes only where the arithmetic is the
same. Between machines it need not be. torch dispatches its CPU kernels by the instruction set it
finds (``torch.backends.cpu.get_cpu_capability``). The tile rasterizer is compiled here, with AVX2
and FMA where the CPU lists both. Two runs whose Stage 2 ends apart (Table 2's footnote,
``eval.tables.stage2_apart``) can be told apart by this line (metrics.json
``provenance.machine.float_setup``, harness.json ``float_setup``).
"""
from __future__ import annotations

import os
import subprocess
from functools import lru_cache

SIMD_PREFIXES = ("sse", "avx", "fma", "amx", "f16c")
"""The /proc/cpuinfo flags that decide which vector code torch and the kernel's compiler use."""


def cpu_facts() -> tuple[str, list[str]]:
    """The CPU's model name and its vector-instruction flags, from /proc/cpuinfo ("unknown" and
    none where there is no such file)."""
    model, flags = "unknown", []
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and model == "unknown":
                    model = value.strip()
                elif key.strip() == "flags" and not flags:
                    flags = sorted(v for v in value.split() if v.startswith(SIMD_PREFIXES))
    except OSError:
        pass
    return model, flags


def compiler_version(compiler: str) -> str:
    """The first line of ``compiler --version``, or why there is none."""
    try:
        done = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError) as exc:
        return f"{compiler}: not run ({type(exc).__name__})"
    lines = done.stdout.strip().splitlines()
    return lines[0] if done.returncode == 0 and lines else f"{compiler}: exit {done.returncode}"


@lru_cache(maxsize=1)
def float_setup() -> str:
    """One line: the CPU and its vector flags, torch's version and CPU capability, and the compiler
    that builds the kernel (``CXX``, else ``c++``, as torch's extension builder picks it)."""
    import torch

    model, flags = cpu_facts()
    return (f"cpu {model} ({' '.join(flags) or 'no vector flags listed'}); "
            f"torch {torch.__version__} {torch.backends.cpu.get_cpu_capability()}; "
            f"compiler {compiler_version(os.environ.get('CXX', 'c++'))}")
