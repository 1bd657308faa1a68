"""Clips on a Dask cluster (fullbody_adjust.cli.cluster), without Blender: a real scheduler and real worker
processes on 127.0.0.1, started and stopped here, running the clip workers of test_batch_pool (small Python
scripts speaking the clip worker's protocol). The whole command on a cluster is tests/blender/test_cli_cluster.py's."""

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from fullbody_adjust.cli import cluster
from fullbody_adjust.cli.pool import WorkerPool

from tests.helpers.dask_cluster import HAS_DISTRIBUTED, WITHOUT_DISTRIBUTED, Cluster
from tests.test_batch_pool import FAKE_WORKER


needs_distributed = pytest.mark.skipif(not HAS_DISTRIBUTED, reason=WITHOUT_DISTRIBUTED)

# A clip worker whose every task takes SLOW seconds (long enough to kill its Dask worker in the middle), then
# answers with its process's parent (the Dask worker) and the job's tag.
SLOW = 3.0
SLOW_WORKER = FAKE_WORKER.replace('    print("chatter that is not a message")',
                                  f'    import time\n    time.sleep({SLOW} if task["clip"].startswith("slow") else 0)\n'
                                  '    print("chatter that is not a message")').replace(
    '"pid": os.getpid()', '"pid": os.getpid(), "parent": os.getppid(), "slept": task["clip"]')


@pytest.fixture
def two_workers(tmp_path):
    running = Cluster(tmp_path, 2)
    yield running
    running.stop()


@needs_distributed
def test_clips_on_the_cluster_give_the_rows_of_the_local_pool(two_workers):
    client = cluster.connect(two_workers.address, timeout=60)
    try:
        client.wait_for_workers(2, timeout=60)
        tasks = [{"clip": c, "size": s} for c, s in (("a", 1), ("crash", 5), ("b", 3), ("c", 2))]
        seen = []
        dask_pool = cluster.DaskPool(client, [cluster.PYTHON, "-c", FAKE_WORKER], {"tag": "job-1"},
                                     on_progress=lambda *a: seen.append(a))
        assert dask_pool.jobs == 2
        ended = []
        rows = dask_pool.run(tasks, on_row=lambda index, row: ended.append(index))
        local = WorkerPool([sys.executable, "-c", FAKE_WORKER], {"tag": "job-1"}, 2).run(tasks)
    finally:
        client.close()
    assert sorted(ended) == [0, 1, 2, 3] and seen[-1] == (4, 1, 1.0)
    strip = ("pid",)
    assert [{k: v for k, v in row.items() if k not in strip} for row in rows] == \
           [{k: v for k, v in row.items() if k not in strip} for row in local]
    assert rows[1]["reason"] == "worker process stopped (exit code 7): about to crash"
    # One clip worker per Dask worker serves its clips (a new one after the crash).
    assert len({row["pid"] for row in rows if "pid" in row}) <= 3


@needs_distributed
def test_a_dask_worker_killed_mid_clip_costs_a_retry_not_the_clip(two_workers, tmp_path):
    client = cluster.connect(two_workers.address, timeout=60)
    try:
        client.wait_for_workers(2, timeout=60)
        pids = client.run(os.getpid)  # {worker address: its process}
        tasks = [{"clip": f"slow{i}"} for i in range(4)]
        dask_pool = cluster.DaskPool(client, [cluster.PYTHON, "-c", SLOW_WORKER], {"tag": "kill"})
        result = {}
        runner = threading.Thread(target=lambda: result.update(rows=dask_pool.run(tasks)))
        runner.start()
        # Kill the Dask worker of the first clip seen running, halfway through its clip.
        victim = None
        deadline = time.monotonic() + 60
        while victim is None and time.monotonic() < deadline:
            busy = [address for address, keys in client.processing().items() if keys]
            victim = busy[0] if busy else None
            time.sleep(0.05)
        assert victim is not None
        time.sleep(SLOW / 2)
        os.kill(pids[victim], signal.SIGKILL)
        runner.join(timeout=120)
        assert not runner.is_alive()
    finally:
        client.close()
    rows = result["rows"]
    assert [row["status"] for row in rows] == ["done"] * 4, rows
    assert [row["slept"] for row in rows] == [task["clip"] for task in tasks]
    assert pids[victim] not in {row["parent"] for row in rows}  # the killed worker answered for none of them
    # No clip worker is left: the killed worker's went with it, the others were closed as the batch ended.
    time.sleep(1.0)
    left = subprocess.run(["pgrep", "-f", f"time.sleep\\({SLOW}"], capture_output=True, text=True).stdout.split()
    assert left == []


@needs_distributed
def test_without_a_scheduler_there_is_one_line():
    with pytest.raises(cluster.ClusterError, match=r"^--scheduler tcp://127.0.0.1:9: cannot reach the scheduler"):
        cluster.connect("tcp://127.0.0.1:9", timeout=2)


def test_without_the_distributed_package_there_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if it were not installed: importing it fails
    with pytest.raises(cluster.ClusterError) as raised:
        cluster.connect("tcp://127.0.0.1:8786")
    assert str(raised.value) == cluster.MISSING and "\n" not in cluster.MISSING
