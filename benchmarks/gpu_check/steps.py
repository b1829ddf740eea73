"""Steps of the GPU check under one time budget: each runs with a timeout no longer than what
is left, is skipped (with the reason) when too little is left or a step it needs did not
succeed, and leaves its output in a log file."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

OK, FAILED, TIMEOUT, SKIPPED = "ok", "failed", "timeout", "skipped"


@dataclass
class StepResult:
    """One step's outcome; ``detail`` holds what it measured."""

    name: str
    status: str
    seconds: float = 0.0
    reason: str = ""
    log: str = ""
    detail: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class Budget:
    """Wall-clock seconds for the whole check, counted from construction."""

    def __init__(self, total_s: float) -> None:
        self.total_s = total_s
        self.start = time.monotonic()

    def left(self) -> float:
        return self.total_s - (time.monotonic() - self.start)

    def timeout_for(self, cap_s: float, reserve_s: float = 0.0) -> float:
        """A step's timeout: its cap, or what is left after ``reserve_s`` for later steps."""
        return min(cap_s, self.left() - reserve_s)


def blocked(name: str, needs: list[str], done: dict[str, StepResult]) -> StepResult | None:
    """A skipped result when a step this one needs did not succeed, else None."""
    for need in needs:
        if need not in done or done[need].status != OK:
            why = "was not run" if need not in done else f"ended {done[need].status}"
            return StepResult(name, SKIPPED, reason=f"needs step '{need}', which {why}")
    return None


def run_command(name: str, argv: list[str], log: Path, timeout_s: float, *, env: dict[str, str] | None = None,
                cwd: Path | None = None, min_s: float = 5.0) -> StepResult:
    """Run ``argv`` with its stdout and stderr in ``log``; on timeout its whole process group is
    ended (SIGTERM, then SIGKILL after 5 s), so compilers and trainers it started go too."""
    if timeout_s < min_s:
        return StepResult(name, SKIPPED, reason=f"time budget: {max(timeout_s, 0):.0f} s left for it, "
                                                f"needs at least {min_s:.0f} s")
    log.parent.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    with open(log, "w") as out:
        out.write("$ " + " ".join(argv) + "\n")
        out.flush()
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=cwd,
                                preexec_fn=os.setpgrp)
        try:
            rc = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            _end_group(proc)
            return StepResult(name, TIMEOUT, time.monotonic() - start,
                              reason=f"stopped after its {timeout_s:.0f} s timeout", log=str(log))
    seconds = time.monotonic() - start
    if rc != 0:
        return StepResult(name, FAILED, seconds, reason=f"exit status {rc}: {last_line(log)}", log=str(log))
    return StepResult(name, OK, seconds, log=str(log))


def _end_group(proc: subprocess.Popen) -> None:
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=5)
            return
        except subprocess.TimeoutExpired:
            continue


def last_line(log: Path) -> str:
    """The log's last non-empty line (the error, for most tools), shortened."""
    lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
    return lines[-1][:300] if lines else "(no output)"
