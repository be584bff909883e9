"""``spcodec tile --cluster ADDRESS`` (issue 39 item 3): the nodes run as tasks on a scheduler that
was running before the command, reached by its address, as on a real cluster, and a worker process
that dies in the middle of a node costs a retry, not the build. The default local workers and a
node that raises are tested in tests/test_tiling.py. Here the "cluster" is a Dask LocalCluster of
two worker processes that the test starts and the command only connects to."""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import pytest
from distributed import WorkerPlugin

from spcodec.cli import main
from spcodec.decoder import decode
from spcodec.ply import write_ply
from spcodec.synthetic import make_scene
from spcodec.tiling.tileset import read_tileset

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("single_torch_thread")]


@pytest.fixture(scope="module")
def small_ply(tmp_path_factory) -> Path:
    """Two leaves and a root (branching 2, leaves of 700): three node tasks."""
    path = tmp_path_factory.mktemp("cluster") / "small.ply"
    write_ply(path, make_scene(seed=1, curves=2, per_curve=250, blobs=900, sh_degree=1).cloud)
    return path


def local_cluster():
    from dask.distributed import LocalCluster

    return LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                        silence_logs=logging.ERROR)


def tile(ply: Path, out: Path, address: str) -> int:
    return main(["tile", str(ply), "-o", str(out), "--cluster", address, "--leaf-size", "700",
                 "--branching", "2"])


def decoded_leaves(out: Path) -> int:
    index = read_tileset(out)
    return sum(len(decode(out / t["content"]["uri"])) for t in index["root"]["children"])


class KillOnce(WorkerPlugin):
    """A Dask worker plugin: the worker process that starts running a task whose key holds
    ``key_part`` exits at once, the first time only (``marker`` is the file that remembers it),
    as a worker killed by the OS or its machine's loss would."""

    def __init__(self, marker: str, key_part: str) -> None:
        self.marker, self.key_part = marker, key_part

    def transition(self, key, start, finish, **kwargs) -> None:
        if finish == "executing" and self.key_part in str(key) and not os.path.exists(self.marker):
            Path(self.marker).write_text(str(os.getpid()))
            os._exit(1)


# a Dask cluster and three node encodes: 1-2 minutes each on a busy 2-core machine
def test_tile_runs_its_nodes_on_the_scheduler_at_the_address(small_ply, tmp_path, capsys):
    from dask.distributed import Client

    out = tmp_path / "tiles"
    with local_cluster() as cluster:
        code = tile(small_ply, out, cluster.scheduler_address)
        with Client(cluster) as client:
            prefixes = client.run_on_scheduler(lambda dask_scheduler: list(dask_scheduler.task_prefixes))
        assert len(cluster.workers) == 2  # the command left the cluster as it found it
    text, err = capsys.readouterr()
    assert code == 0, err
    assert "3 nodes (2 leaves, depth 1), 1,400 Gaussians in" in text
    assert "3 nodes encoded this run" in text
    assert any(p.startswith("spcodec-tile") for p in prefixes), prefixes  # ran there, not here
    assert decoded_leaves(out) == 1400


def test_a_worker_killed_in_a_node_costs_a_retry_not_the_build(small_ply, tmp_path, capsys):
    import cloudpickle
    from dask.distributed import Client

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import tests/
    marker, out = tmp_path / "killed", tmp_path / "tiles"
    with local_cluster() as cluster, Client(cluster) as client:
        client.register_plugin(KillOnce(str(marker), "spcodec-tile-n0-"), name="kill-once")
        code = tile(small_ply, out, cluster.scheduler_address)
    text, err = capsys.readouterr()
    assert marker.exists(), "no worker was killed: the test tested nothing"
    assert code == 0, err
    assert "3 nodes encoded this run" in text
    assert decoded_leaves(out) == 1400


def test_an_unreachable_cluster_is_one_line_before_anything_is_written(small_ply, tmp_path,
                                                                      capsys):
    """A wrong address is the user's mistake (exit 2), found before the input is partitioned:
    no ``work/`` (a copy of the whole input) is left behind, nor the output folder."""
    import dask

    out = tmp_path / "tiles"
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):  # not the default 30 s
        code = tile(small_ply, out, "tcp://127.0.0.1:9")
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert "cannot reach the Dask scheduler at --cluster tcp://127.0.0.1:9" in err, err
    assert not out.exists()


@pytest.mark.parametrize("address, reason", [("localhost", "missing port number"),
                                             ("nonsense://x:1", "unknown address scheme")])
def test_an_address_that_is_no_address_is_one_line(small_ply, tmp_path, capsys, address, reason):
    out = tmp_path / "tiles"
    assert tile(small_ply, out, address) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and reason in err and not out.exists(), err
