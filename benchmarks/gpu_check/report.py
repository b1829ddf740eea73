"""The check's two outputs: ``gpu_check.json`` (everything) and ``gpu_check.md`` (a short page).
Both are written whole or not at all (contracts.atomic)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from contracts.atomic import write_json, write_text


def _num(value: Any, fmt: str) -> str:
    return "—" if value is None else format(value, fmt)


def markdown(results: dict[str, Any]) -> str:
    """The short page: node, steps with status and time, and the measured figures."""
    node = results["node"]
    lines = [f"# GPU check, {results['date']}", "",
             f"- GPU: {', '.join(node.get('gpus') or []) or 'none'} (compute capability "
             f"{', '.join(node.get('capabilities') or []) or '—'})",
             f"- Python {node.get('python')}, torch {node.get('torch')} (CUDA {node.get('torch_cuda')}), "
             f"nvcc {node.get('nvcc')}, {node.get('cpus')} CPUs",
             f"- Commit {results.get('commit') or 'unknown'}; budget {results['budget_s']:.0f} s, used "
             f"{results['elapsed_s']:.0f} s", "",
             "| step | status | seconds | note |", "|---|---|---|---|"]
    for step in results["steps"]:
        lines.append(f"| {step['name']} | {step['status']} | {step['seconds']:.1f} | {step['reason']} |")
    runs = results.get("runs", {})
    if runs:
        lines += ["", "| run | backend | Stage 2 it/s | Stage 3 it/s | iterations (Stage 2 + 3) | peak GPU memory (GiB) | test PSNR |",
                  "|---|---|---|---|---|---|---|"]
        for name, run in runs.items():
            rate = run.get("iterations_per_s", {})
            mem = run.get("peak_memory_bytes")
            done = " + ".join(str(v) for _, v in sorted(run.get("iterations_done", {}).items())) or "—"
            lines.append(f"| {name} | {run.get('backend', '—')} | {_num(rate.get('2'), '.2f')} | "
                         f"{_num(rate.get('3'), '.2f')} | {done} | "
                         f"{_num(None if mem is None else mem / 2**30, '.2f')} | {_num(run.get('psnr'), '.2f')} |")
    ref = results.get("reference")
    if ref:
        lines += ["", f"CPU reference ({ref['runs_folder']}, trainer {ref['source_digest'][:8]}): seed 0 "
                      f"{ref['seed0_psnr']:.2f} dB, seeds {ref['seeds']} span {ref['spread_db']:.2f} dB."]
        if results.get("psnr_verdict"):
            lines.append(results["psnr_verdict"])
    for note in results.get("notes", []):
        lines += ["", note]
    return "\n".join(lines) + "\n"


def relative_paths(value: Any, root: Path) -> Any:
    """``value`` with every path under ``root`` written relative to it, so a report names the
    checkout's files the same on every machine."""
    if isinstance(value, dict):
        return {k: relative_paths(v, root) for k, v in value.items()}
    if isinstance(value, list):
        return [relative_paths(v, root) for v in value]
    if isinstance(value, str):
        return value.replace(f"{root}/", "")
    return value


def write_report(out: Path, results: dict[str, Any], root: Path | None = None) -> tuple[Path, Path]:
    """Write both files into ``out`` (paths under ``root`` made relative); returns their paths."""
    if root is not None:
        results = relative_paths(results, root)
    out.mkdir(parents=True, exist_ok=True)
    json_path, md_path = out / "gpu_check.json", out / "gpu_check.md"
    write_json(json_path, results)
    write_text(md_path, markdown(results))
    return json_path, md_path
