"""How the encoder spreads tasks over cores (encoder/threads.py)."""

from __future__ import annotations

import threading

import numpy as np
from threadpoolctl import threadpool_info

from spcodec.encoder.threads import default_jobs, map_tasks


def test_results_come_back_in_the_order_of_the_tasks_whatever_the_threads():
    tasks = list(range(23))
    for jobs in (1, 2, 5, None):
        assert map_tasks(lambda t: t * t, tasks, jobs, cost=lambda t: t % 7) == \
            [t * t for t in tasks]
    assert map_tasks(lambda t: t, [], 3) == []


def test_the_costliest_tasks_start_first():
    started: list[int] = []
    map_tasks(started.append, [3, 9, 1, 7], 1, cost=lambda t: t)
    assert started == [9, 7, 3, 1]


def test_each_task_runs_on_one_library_thread_and_jobs_threads_run_them():
    seen_threads: set[int] = set()
    barrier = threading.Barrier(2, timeout=10)

    def task(_: int) -> list[int]:
        seen_threads.add(threading.get_ident())
        barrier.wait()  # two tasks at once: only possible on two threads
        return [pool["num_threads"] for pool in threadpool_info()]

    limits = map_tasks(task, [0, 1], 2)
    assert len(seen_threads) == 2
    assert all(n == 1 for pools in limits for n in pools), limits
    # and the limit is lifted afterwards (numpy keeps working as configured)
    assert np.ones((2, 2)).sum() == 4.0


def test_default_jobs_is_at_least_one():
    assert default_jobs() >= 1
