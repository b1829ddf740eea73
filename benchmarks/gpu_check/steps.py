"""Steps of the GPU check under one time budget: each runs with a timeout no longer than what
is left, is skipped (with the reason) when too little is left or a step it needs did not
succeed, and leaves its output in a log file."""
from __future__ import annotations

import os
import signal
import subprocess
import threading
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


class Running:
    """A step started in the background: it runs beside the steps that follow until ``wait``."""

    def __init__(self, name: str, argv: list[str], log: Path, timeout_s: float, *, env: dict[str, str] | None,
                 cwd: Path | None, nice: int = 0) -> None:
        self.name, self.log, self.timeout_s = name, log, timeout_s
        log.parent.mkdir(parents=True, exist_ok=True)
        self.start = time.monotonic()
        with open(log, "w") as out:
            out.write("$ " + " ".join(argv) + "\n")
            out.flush()
            self.proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=cwd,
                                         preexec_fn=lambda: (os.setpgrp(), os.nice(nice)))
        self.ended = self.start  # set when the process exits, not when it is waited for
        self._reaper = threading.Thread(target=self._reap, daemon=True)  # the one waiter on the process
        self._reaper.start()

    def _reap(self) -> None:
        self.proc.wait()
        self.ended = time.monotonic()

    def wait(self, stop_at_s: float | None = None) -> StepResult:
        """The outcome; the step is stopped (with its children) at its own timeout, or after
        ``stop_at_s`` more seconds when that comes first."""
        left = self.timeout_s - (time.monotonic() - self.start)
        limit = left if stop_at_s is None else min(left, stop_at_s)
        self._reaper.join(timeout=max(limit, 0.0))
        if self._reaper.is_alive():
            _end_group(self.proc)
            why = (f"its {self.timeout_s:.0f} s timeout" if limit == left
                   else "the end of the check's time budget")
            return StepResult(self.name, TIMEOUT, time.monotonic() - self.start, reason=f"stopped at {why}",
                              log=str(self.log))
        rc, seconds = self.proc.returncode, self.ended - self.start
        if rc != 0:
            return StepResult(self.name, FAILED, seconds, reason=f"exit status {rc}: {last_line(self.log)}",
                              log=str(self.log))
        return StepResult(self.name, OK, seconds, log=str(self.log))


def start_command(name: str, argv: list[str], log: Path, timeout_s: float, *, env: dict[str, str] | None = None,
                  cwd: Path | None = None, min_s: float = 5.0, nice: int = 0) -> Running | StepResult:
    """Start ``argv`` with its stdout and stderr in ``log`` (a skipped result when less than
    ``min_s`` is left for it)."""
    if timeout_s < min_s:
        return StepResult(name, SKIPPED, reason=f"time budget: {max(timeout_s, 0):.0f} s left for it, "
                                                f"needs at least {min_s:.0f} s")
    return Running(name, argv, log, timeout_s, env=env, cwd=cwd, nice=nice)


def run_command(name: str, argv: list[str], log: Path, timeout_s: float, *, env: dict[str, str] | None = None,
                cwd: Path | None = None, min_s: float = 5.0) -> StepResult:
    """Run ``argv`` with its stdout and stderr in ``log``; on timeout its whole process group is
    ended (SIGTERM, then SIGKILL after 5 s), so compilers and trainers it started go too."""
    started = start_command(name, argv, log, timeout_s, env=env, cwd=cwd, min_s=min_s)
    return started if isinstance(started, StepResult) else started.wait()


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
