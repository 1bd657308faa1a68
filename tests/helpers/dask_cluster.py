"""A Dask cluster on 127.0.0.1 for the tests: a scheduler and worker processes of this Python, started and stopped
by the test (tests/test_dask_pool.py, tests/blender/test_cli_cluster.py)."""

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time

HAS_DISTRIBUTED = importlib.util.find_spec("distributed") is not None
WITHOUT_DISTRIBUTED = "the 'distributed' package is not importable in this Python (.ci/with-bpy installs it)"


class Cluster:
    """A scheduler and ``workers`` Dask worker processes (one thread each, under a nanny) on 127.0.0.1."""

    def __init__(self, folder, workers):
        self.file = str(folder / "scheduler.json")
        self.log = open(folder / "cluster.log", "ab")
        common = ["--no-dashboard"]
        self.processes = [self._start("dask_scheduler", "--host", "127.0.0.1", "--port", "0",
                                      "--scheduler-file", self.file, *common)]
        self.address = self._address(deadline=time.monotonic() + 60)
        self.workers = [self._start("dask_worker", self.address, "--host", "127.0.0.1", "--nthreads", "1",
                                    "--nworkers", "1", *common) for _ in range(workers)]
        self.processes += self.workers

    def ready(self, timeout=60.0):
        """Wait until every worker has joined the scheduler (a cluster that runs on has them all before a batch)."""
        import distributed

        with distributed.Client(self.address, timeout=timeout, set_as_default=False) as client:
            client.wait_for_workers(len(self.workers), timeout=timeout)
        return self

    def _address(self, deadline):
        """The scheduler's address, from its file once written whole."""
        while time.monotonic() < deadline:
            try:
                with open(self.file) as f:
                    return json.load(f)["address"]
            except (OSError, ValueError, KeyError):
                time.sleep(0.1)
        self.stop()
        raise RuntimeError("the Dask scheduler did not start in 60 s")

    def _start(self, program, *arguments):
        return subprocess.Popen([sys.executable, "-m", f"distributed.cli.{program}", *arguments],
                                stdout=self.log, stderr=self.log, start_new_session=True)

    def stop(self):
        for process in reversed(self.processes):
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGTERM)
        for process in self.processes:
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
        self.log.close()
