"""A gsplat wheel compiled ahead of time for one kind of GPU node, carried in the wheel folder.

gsplat's CUDA extension is tied to the Python, torch and CUDA it was compiled with and to the GPU
architectures it was compiled for. The compile needs those and nvcc, not a GPU, so it can run on
any Linux x86-64 machine that has them (make it with ``python -m
benchmarks.gpu_check.prebuild_gsplat``). The record beside the wheel says what it was built for;
the check installs the wheel only on a node that matches it and otherwise compiles the source
archive, saying why.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

RECORD = "gsplat-prebuilt.json"
MATCHED = ("python", "torch", "torch_cuda", "arch_list")
"""What a node must share with the build: the interpreter's ABI, torch's C++ ABI and CUDA
runtime, and the compiled architectures (TORCH_CUDA_ARCH_LIST)."""


@dataclass
class PrebuiltRecord:
    """What one prebuilt wheel was compiled for and how long the compile took."""

    wheel: str
    python: str  # major.minor
    torch: str
    torch_cuda: str
    arch_list: str
    nvcc: str
    seconds: float
    jobs: int
    cpus: int

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _major_minor(version: str | None) -> str:
    return ".".join((version or "").split(".")[:2])


def node_values(node: dict[str, Any]) -> dict[str, str]:
    """The MATCHED values of a probed node (benchmarks.gpu_check.target.probe)."""
    return {"python": _major_minor(node.get("python")), "torch": str(node.get("torch")),
            "torch_cuda": str(node.get("torch_cuda")), "arch_list": str(node.get("arch_list"))}


def read_record(folder: Path) -> PrebuiltRecord | None:
    """The folder's prebuilt record, None when it has none. Raises ValueError naming the file and
    field when the record is unreadable or its wheel is missing."""
    path = folder / RECORD
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
        record = PrebuiltRecord(**{k: doc[k] for k in PrebuiltRecord.__dataclass_fields__})
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc.msg})") from None
    except KeyError as exc:
        raise ValueError(f"{path}: field {exc.args[0]!r} is missing") from None
    if not (folder / record.wheel).is_file():
        raise ValueError(f"{path}: wheel: {record.wheel} is not in {folder}")
    return record


def mismatches(record: PrebuiltRecord, node: dict[str, Any]) -> list[str]:
    """One line per MATCHED value in which the node differs from the build (empty: usable)."""
    have = node_values(node)
    built = {"python": record.python, "torch": record.torch, "torch_cuda": record.torch_cuda,
             "arch_list": record.arch_list}
    return [f"{key}: built for {built[key]}, the node has {have[key]}" for key in MATCHED if built[key] != have[key]]
