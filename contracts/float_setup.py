"""What sets a run's float rounding on this machine, for its provenance and its harness record.

The same settings, data, code and seed train to the same bytes only where the arithmetic is the
same. Between machines it need not be. torch dispatches its CPU kernels by the instruction set it
finds (``torch.backends.cpu.get_cpu_capability``). The tile rasterizer is compiled here, with AVX2
and FMA where the CPU lists both. Two runs whose Stage 2 ends apart (Table 2's footnote,
``eval.tables.stage2_apart``) can be told apart by this line (metrics.json
``provenance.machine.float_setup``, harness.json ``float_setup``).

One machine can train under two float setups: ``HELD_TO`` lists the environment that holds torch's
own kernels, oneDNN and MKL to an instruction set (``benchmarks/float_setup.py`` trains the same
run under each and reports the difference). The variables are read when torch first dispatches,
so they must be set before the process starts.
"""
from __future__ import annotations

import os
import subprocess
from functools import lru_cache

SIMD_PREFIXES = ("sse", "avx", "fma", "amx", "f16c")
"""The /proc/cpuinfo flags that decide which vector code torch and the kernel's compiler use."""

HELD_TO: dict[str, dict[str, str]] = {
    "default": {},
    "avx2": {"ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2", "MKL_ENABLE_INSTRUCTIONS": "AVX2"},
}
"""The environment of each float setup one machine can train under: its own default, or torch,
oneDNN and MKL held to AVX2 (the instruction set of the other machines runs meet)."""
ISA_VARIABLES = tuple(sorted({k for env in HELD_TO.values() for k in env}))

KERNEL_VECTOR_FLAGS = ["-mavx2", "-mfma"]
"""The tile rasterizer's vector flags, given where the CPU lists both avx2 and fma. Never
-march=native and never AVX-512, so the kernel's arithmetic is the same on an AVX2 and an AVX-512
machine (only torch's own kernels, oneDNN and MKL differ between them)."""


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


def kernel_vector_flags(flags: list[str] | None = None) -> list[str]:
    """The kernel's vector flags on a CPU with ``flags`` (this machine's by default)."""
    listed = set(cpu_facts()[1] if flags is None else flags)
    return list(KERNEL_VECTOR_FLAGS) if {"avx2", "fma"} <= listed else []


def held_isa() -> str:
    """The ISA variables set in this process's environment, ``NAME=value`` joined, or "none"."""
    held = [f"{k}={os.environ[k]}" for k in ISA_VARIABLES if os.environ.get(k)]
    return " ".join(held) or "none"


@lru_cache(maxsize=1)
def float_setup() -> str:
    """One line: the CPU and its vector flags, torch's version and CPU capability, the ISA variables
    held in the environment, the kernel's vector flags and the compiler that builds it (``CXX``, else
    ``c++``, as torch's extension builder picks it)."""
    import torch

    model, flags = cpu_facts()
    return (f"cpu {model} ({' '.join(flags) or 'no vector flags listed'}); "
            f"torch {torch.__version__} {torch.backends.cpu.get_cpu_capability()}; held {held_isa()}; "
            f"kernel {' '.join(kernel_vector_flags(flags)) or 'scalar'}; "
            f"compiler {compiler_version(os.environ.get('CXX', 'c++'))}")


def machine_of(line: str) -> str:
    """The CPU model and torch capability of a ``float_setup()`` line (``cpu MODEL (flags); torch
    VERSION CAPABILITY; ...``), or "not recorded" for an empty line or one of another shape."""
    if not line.startswith("cpu "):
        return "not recorded"
    model = line[4:].split(" (", 1)[0]
    torch_part = next((p.strip() for p in line.split(";") if p.strip().startswith("torch ")), "")
    return f"{model} {torch_part.split()[-1]}" if torch_part else model
