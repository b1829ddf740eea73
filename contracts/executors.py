"""Where long tasks run: a local process pool or a Dask scheduler, behind one interface, so the
harness's trainings and the benchmark's scene generations are scheduled the same way."""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Protocol


@dataclass
class Executor:
    submit: Callable[..., Any]
    as_completed: Callable[[list[Any]], Iterator[Any]]
    description: str


class Progress(Protocol):
    def update(self, n: int = 1) -> Any: ...


@contextmanager
def open_executor(workers: int, scheduler: str | None) -> Iterator[Executor]:
    """A spawn-context process pool by default; "local" starts a Dask LocalCluster with
    one single-threaded worker per slot; any other value is a Dask scheduler address."""
    if scheduler is None:
        ctx = multiprocessing.get_context("spawn")  # bpy/torch state must not be forked
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            yield Executor(pool.submit, cf.as_completed, f"process pool, {workers} worker(s)")
        return
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True)
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="30s")
    try:
        yield Executor(lambda fn, *a: client.submit(fn, *a, pure=False), as_completed,
                       f"dask scheduler {client.scheduler.address}")
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


Job = tuple[Any, tuple[Any, ...], Callable[[Any], Any], Callable[[BaseException], Any]]
"""A task for ``drain``: the function, its arguments, and the callbacks for its result and for a
crash; a callback may return further jobs, which are submitted then."""


def drain(ex: Executor, jobs: list[Job], bar: Progress) -> None:
    """Submit every job, then route each result (or a worker crash) to its callback, and submit
    the jobs a callback returns (work that waits on another job's result)."""
    futures: dict[Any, tuple[Callable[[Any], Any], Callable[[BaseException], Any]]] = {}

    def submit(batch: list[Job]) -> None:
        for fn, args, ok, fail in batch:
            futures[ex.submit(fn, *args)] = (ok, fail)

    submit(jobs)
    while futures:
        for fut in ex.as_completed(list(futures)):
            ok, fail = futures.pop(fut)
            try:
                value = fut.result()
            except Exception as exc:  # a worker died (e.g. a native abort): the task failed
                more = fail(exc)
            else:
                more = ok(value)
            bar.update(1)
            if more:
                submit(more)
                break  # wait on the new futures too
