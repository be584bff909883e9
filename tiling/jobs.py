"""Node tasks on Dask distributed: a local cluster by default, or a running scheduler.

Dask rather than Ray (both measured on the 2-core development machine, a local cluster of two
single-threaded workers running 50 trivial tasks): Dask started in 0.5-0.7 s and shut down in
0.1-0.15 s, Ray in 2.1-2.3 s and 1.1-1.35 s; the tasks themselves took 0.09 s against 0.04 s,
noise next to encodes of seconds each. Dask is a pure-Python install, its ``retries=`` re-runs a
failed task, futures passed as arguments make a task wait for its children (so the tree runs
bottom-up without a hand-written scheduler), and ``Client(address)`` reaches a real cluster.
"""

from __future__ import annotations

import logging
import os
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, Iterator

from spcodec.errors import UsageError

from .build import NodeJob, build_node
from .config import TilingConfig

if TYPE_CHECKING:
    from dask.distributed import Client

    from spcodec.encoder.stages import Stage


@contextmanager
def engine(config: TilingConfig) -> Iterator[Client | None]:
    """The Dask client the nodes run on (None: this process, ``workers=0`` and no cluster).

    Entered before any pass over the input, so that a scheduler that cannot be reached or a Dask
    that is not installed is a user's one-line error at once, not after a partition that takes
    minutes at 20 M Gaussians and leaves its spilled leaves behind."""
    if config.workers == 0 and config.cluster is None:
        yield None
        return
    client, cluster = connect(config)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def connect(config: TilingConfig) -> tuple[Client, Any]:
    """A client of the scheduler at ``config.cluster``, or of a local cluster of
    ``config.workers`` single-threaded processes (returned too, to be closed with it)."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:
        where = "--cluster" if config.cluster else f"{config.workers} local workers"
        raise UsageError(f"{where} needs Dask ({exc.name or 'distributed'} is not installed): "
                         "pip install 'spcodec[tiling]', or encode in this process with "
                         "--workers 0") from None
    if config.cluster is None:
        import dask

        settings = {"distributed.nanny.pre-spawn-environ": worker_environment(), **QUIET}
        with dask.config.set(settings), _unset_environ(MALLOC_TRIM):
            cluster = LocalCluster(n_workers=config.workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.ERROR,
                                   env={"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
        return Client(cluster), cluster
    try:
        return Client(config.cluster), None
    except (OSError, ValueError, TypeError) as exc:  # refused, timed out, or not an address
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UsageError(f"cannot reach the Dask scheduler at --cluster {config.cluster}: "
                         f"{reason}") from None


MALLOC_TRIM = "MALLOC_TRIM_THRESHOLD_"

QUIET = {"distributed.worker.profile.enabled": False,
         "distributed.admin.tick.interval": "1s",
         "distributed.admin.system-monitor.interval": "5s",
         "distributed.worker.memory.monitor-interval": "1s"}
"""Dask's watchers of a local cluster slowed to what a build of minutes-long tasks needs.

By default the worker samples its task's stack every 10 ms (its profiler), the event loops tick
every 20 ms, the nanny reads the worker's memory every 100 ms and every process reads its system
counters every 500 ms: an idle one-worker cluster cost 4 CPU s a minute, 7 % of a core, and a
tileset's build is minutes of wall time (docs/LOG.md). Scheduling (work stealing included) is
left as it is. The nanny hands its configuration to the worker it starts, so the settings reach
the worker process; nothing here changes what a task computes. A cluster reached by
``--cluster`` keeps its owner's settings."""


@contextmanager
def _unset_environ(name: str) -> Iterator[None]:
    """``name`` out of this process's environment while workers are spawned (they inherit it).

    A nanny writes its pre-spawn environment into its own process's ``os.environ`` and never
    takes it back, so once any Dask cluster with the defaults has run here (a test, a notebook),
    the variable would reach every later worker from the parent."""
    saved = os.environ.pop(name, None)
    try:
        yield
    finally:
        if saved is not None:
            os.environ[name] = saved


def worker_environment() -> dict:
    """Dask's environment for new worker processes without ``MALLOC_TRIM_THRESHOLD_``.

    Dask sets it (65536) so that workers hand freed memory back at once; the encoder's numpy
    temporaries are then mapped and unmapped again on every call, and the same 250 k merge cost
    13-15 CPU s in a worker against 7-8 in a plain process (docs/LOG.md 22.5). A node's memory is
    bounded by its tile, so keeping freed pages costs nothing that matters. Workers of a cluster
    reached by ``--cluster`` are started by their owner (the README says so)."""
    import dask

    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    environ.pop(MALLOC_TRIM, None)
    return environ


def run_nodes(jobs: list[NodeJob], client: Client | None, retries: int,
              stage: Stage | None = None) -> dict[str, dict]:
    """Every job's record by node id; ``jobs`` lists each node after its children. ``stage``
    counts the nodes as they complete (on Dask, in whatever order the workers finish them)."""
    if stage is None:
        from spcodec.encoder.stages import Stage

        stage = Stage()
    if client is None:
        return run_here(jobs, stage)
    return run_on_dask(jobs, client, retries, stage)


def run_here(jobs: list[NodeJob], stage: Stage) -> dict[str, dict]:
    """In this process, one node after another (no engine, no retries), torch on one thread
    as in a worker (:func:`node_task`), restored afterwards: on torch's default threads a
    searched node took 55 s instead of 6 on the loaded 2-core machine (docs/LOG.md 28)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        records: dict[str, dict] = {}
        for job in jobs:
            records[job.id] = build_node(job, [records[c] for c in job.children])
            stage.update()
        return records
    finally:
        torch.set_num_threads(threads)


def run_on_dask(jobs: list[NodeJob], client: Client, retries: int,
                stage: Stage) -> dict[str, dict]:
    """On a Dask cluster: a task per node, depending on its children's tasks, each retried up to
    ``retries`` times. The first node that fails for good ends the build with its error."""
    from dask.distributed import as_completed

    futures: dict[str, Any] = {}
    for job in jobs:
        futures[job.id] = client.submit(
            node_task, job, [futures[c] for c in job.children], retries=retries,
            pure=False, key=f"spcodec-tile-{job.id}-{id(futures):x}")
    for future in as_completed(list(futures.values())):
        if future.status == "error":
            future.result()  # raises the node's own exception
        stage.update()
    results = client.gather([futures[job.id] for job in jobs])
    return {job.id: record for job, record in zip(jobs, results)}


def node_task(job: NodeJob, children: list[dict]) -> dict:
    """:func:`.build.build_node` with torch on one thread: each worker is one core's worth."""
    import torch

    torch.set_num_threads(1)
    return build_node(job, children)
