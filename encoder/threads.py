"""How the encoder spreads independent tasks over cores.

The libraries under the encoder (numpy's BLAS, scikit-learn's OpenMP) thread their own inner
loops over every core. On a shared 2-core machine those fine-grained threads stall whenever
another process runs, and burn CPU time waiting (docs/LOG.md 27.1). The encoder instead runs
whole tasks (an attribute's codebooks, its precision options) on ``jobs`` threads of its own,
each task on one library thread, so ``--jobs 1`` means one core and results never depend on the
thread count.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence, TypeVar

T = TypeVar("T")
R = TypeVar("R")


def default_jobs() -> int:
    """Cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def map_tasks(fn: Callable[[T], R], tasks: Sequence[T], jobs: int | None,
              cost: Callable[[T], float] | None = None) -> list[R]:
    """``[fn(t) for t in tasks]`` on ``jobs`` threads (None: :func:`default_jobs`), each task
    with one BLAS/OpenMP thread; the costliest tasks (by ``cost``) start first so that the
    threads finish together. Results come back in the order of ``tasks``."""
    from threadpoolctl import threadpool_limits

    order = list(range(len(tasks)))
    if cost is not None:
        order.sort(key=lambda i: -cost(tasks[i]))
    jobs = min(jobs or default_jobs(), max(len(tasks), 1))

    def run(i: int) -> R:
        # OpenMP's thread count belongs to the thread that sets it: each worker sets its own
        with threadpool_limits(limits=1, user_api="openmp"):
            return fn(tasks[i])

    with threadpool_limits(limits=1):  # BLAS's count is the process's: set once, here
        if jobs <= 1:
            results = [fn(tasks[i]) for i in order]
        else:
            with ThreadPoolExecutor(jobs) as pool:
                results = list(pool.map(run, order))
    out: list = [None] * len(tasks)
    for i, result in zip(order, results):
        out[i] = result
    return out
