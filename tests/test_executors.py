"""contracts/executors.py: every job's result reaches its callback, follow-up jobs included."""
from __future__ import annotations

import operator

from contracts.executors import drain, open_executor


class Count:
    def __init__(self) -> None:
        self.n = 0

    def update(self, n: int = 1) -> None:
        self.n += n


def test_drain_runs_the_jobs_a_callback_returns_and_routes_a_crash() -> None:
    got: dict[str, object] = {}
    bar = Count()

    def first(value: int) -> list:
        got["first"] = value
        return [(operator.mul, (value, 10), lambda v: got.__setitem__("second", v), got.__setitem__)]

    jobs = [(operator.add, (2, 3), first, lambda exc: None),
            (operator.truediv, (1, 0), lambda v: None, lambda exc: got.__setitem__("crash", type(exc).__name__))]
    with open_executor(2, None) as ex:
        drain(ex, jobs, bar)
    assert got == {"first": 5, "second": 50, "crash": "ZeroDivisionError"}
    assert bar.n == 3
