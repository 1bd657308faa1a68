# SPDX-License-Identifier: GPL-3.0-or-later
"""Clips on a Dask cluster instead of the local pool (``retarget --source-file ... --scheduler ADDRESS``; no bpy
here, and the ``distributed`` package only once a batch uses it).

Each clip is one Dask task. A Dask worker runs it in the same clip worker process as ``--jobs`` (``pool``'s
_Worker talking to ``python -m fullbody_adjust --clip-worker``, started with the Dask worker's own Python), kept
between the clips of a batch so a worker pays Blender's start once, and closed when the batch ends (or, when the
batch was interrupted, as the worker's next batch starts). A clip that
fails is a row with its reason, as with ``--jobs``; a Dask worker that dies mid-clip takes its clip worker with it
(which ends as soon as its parent is gone, so it writes nothing more), and the scheduler runs the clip again on
another worker: a retry, not a lost clip (up to the scheduler's ``distributed.scheduler.allowed-failures``).

Files are named by their absolute paths: the input .blend, the clips and the outputs must be on storage every
worker sees under the same path, as render farms have.

What runs on a Dask worker (``_run_clip``, ``_close_clip_workers`` and pool's _Worker) is sent by value
(cloudpickle), so the Dask worker needs no copy of this package under an importable name: only its clip workers
do, found on the path the client gives (shared storage) or on the Dask worker's own PYTHONPATH.
"""

import os
import pickle
import sys
import threading
import uuid

from . import pool
from .pool import _Worker, attempt
from ..reporting.batch_report import FAILED

PYTHON = "{python}"  # in a clip worker's command: the Dask worker's own Python
MISSING = ("--scheduler needs the 'distributed' package in this Python (pip install distributed), and the same "
           "on every Dask worker")
_STATE = "_fullbody_adjust_clip_workers"  # the attribute of a Dask worker that holds its idle clip workers


class ClusterError(Exception):
    """The cluster cannot be used: one line."""


def connect(address, timeout=10.0):
    """A distributed.Client of the scheduler at ``address`` (e.g. tcp://10.0.0.5:8786). ClusterError (one line)
    when the package is missing, the scheduler cannot be reached in ``timeout`` seconds or has no worker."""
    try:
        import distributed
    except ImportError:
        raise ClusterError(MISSING) from None
    try:
        client = distributed.Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError, TypeError) as ex:
        reason = " ".join(str(ex).split()) or type(ex).__name__
        raise ClusterError(f"--scheduler {address}: cannot reach the scheduler ({reason})") from None
    try:
        client.wait_for_workers(1, timeout=timeout)
    except (OSError, TimeoutError):
        client.close()
        raise ClusterError(f"--scheduler {address}: the scheduler has no worker (none came in {timeout:g} s)") \
            from None
    return client


class DaskPool:
    """WorkerPool's run() on a Dask cluster. ``command``: a clip worker's argv, PYTHON standing for the Dask
    worker's Python; ``env``: variables for the clip workers, set where the Dask worker has none (PYTHONPATH is put
    in front of the Dask worker's own). ``on_progress(done, failed, fraction)`` as clips end; ``timeout``: seconds a
    clip may run on its worker before it is stopped and fails."""

    def __init__(self, client, command, job, *, env=None, on_progress=None, timeout=None):
        self.client = client
        self.command = list(command)
        self.job = dict(job, watch_parent=True)
        self.env = dict(env or {})
        self.timeout = timeout
        self.on_progress = on_progress or (lambda done, failed, fraction: None)

    @property
    def jobs(self):
        """Clips the cluster runs at once: its workers' threads."""
        return sum(self.client.nthreads().values())

    def run(self, tasks, on_row=None):
        """The row of every task, in the order given, as WorkerPool.run; ``on_row(index, row)`` in this thread
        as each ends. On KeyboardInterrupt the clips not started are cancelled and the interrupt goes on."""
        from distributed import as_completed

        tasks = list(tasks)
        batch = uuid.uuid4().hex
        largest_first = sorted(range(len(tasks)), key=lambda i: -tasks[i].get("size", 0))
        futures = {}
        for rank, index in enumerate(largest_first):
            payload = _sent(_run_clip, batch, self.command, self.env, self.job, tasks[index], self.timeout)
            future = self.client.submit(pickle.loads, payload, key=f"fullbody-adjust-clip-{batch}-{index}",
                                        pure=False, priority=len(tasks) - rank)
            futures[future] = index
        rows = [None] * len(tasks)
        done = failed = 0
        try:
            for future in as_completed(futures, loop=self.client.loop):
                index = futures[future]
                rows[index] = _row_of(future, tasks[index])
                done += 1
                failed += rows[index].get("status") == FAILED
                self.on_progress(done, failed, done / len(tasks))
                if on_row is not None:
                    on_row(index, rows[index])
        except BaseException:  # an interrupt: the clips not started are cancelled (idle clip workers are closed by
            self.client.cancel(list(futures))  # their Dask worker's next batch)
            raise
        self._close(batch)
        return rows

    def _close(self, batch):
        """Close the batch's clip workers: a task on each Dask worker (one left out, as one gone meanwhile, keeps
        its idle clip workers until its next batch)."""
        from distributed import wait

        payload = _sent(_close_clip_workers, batch)
        try:
            closing = [self.client.submit(pickle.loads, payload, key=f"fullbody-adjust-close-{batch}-{k}",
                                          workers=[address], allow_other_workers=False, pure=False)
                       for k, address in enumerate(self.client.nthreads())]
            wait(closing, timeout=60)
        except Exception:  # a worker gone meanwhile (its clip workers went with it), or the client closing
            pass


def _row_of(future, task):
    """The row a finished Dask task gave, or a failed row saying why it gave none."""
    from distributed import KilledWorker

    try:
        return future.result()
    except KilledWorker:
        return {"clip": task["clip"], "status": FAILED,
                "reason": "every Dask worker that ran it died (the scheduler's allowed-failures)"}
    except Exception as ex:
        return {"clip": task["clip"], "status": FAILED,
                "reason": f"internal error on the Dask worker: {type(ex).__name__}: {' '.join(str(ex).split())}"}


class _Call:
    """Pickles as the call ``func(*args)``: unpickling it runs the call (pickle's own __reduce__ protocol), so
    the Dask task is ``pickle.loads(payload)`` and the worker imports nothing of this package by name."""

    def __init__(self, func, *args):
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args


def _sent(func, *args):
    """The payload of ``func(*args)`` for a Dask worker: this module and pool's sent by value."""
    import cloudpickle

    for module in (sys.modules[__name__], pool):
        if module.__name__ not in cloudpickle.list_registry_pickle_by_value():
            cloudpickle.register_pickle_by_value(module)
    return cloudpickle.dumps(_Call(func, *args))


# --- on a Dask worker ---------------------------------------------------------------------------------------------

def _run_clip(batch, command, env, job, task, timeout):
    """On a Dask worker: the row of one clip, run by one of this worker's clip workers of ``batch`` (an idle
    one, or a new one). Never raises but for a bug."""
    import tempfile

    from distributed import get_worker

    host = get_worker()
    state = host.__dict__.setdefault(_STATE, {"batch": None, "idle": [], "lock": threading.Lock()})
    with state["lock"]:
        if state["batch"] != batch:  # a new batch: the last one's clip workers go
            _close_all(state["idle"])
            state["batch"] = batch
        worker = state["idle"].pop() if state["idle"] else None
    if worker is None or worker.process.poll() is not None:
        log = os.path.join(tempfile.gettempdir(), f"fullbody-adjust-clip-worker-{uuid.uuid4().hex}.log")
        argv = [sys.executable if part == PYTHON else part for part in command]
        try:
            worker = _Worker(argv, _environment(env), log, job)
        except OSError as ex:
            return {"clip": task["clip"], "status": FAILED, "reason": f"cannot start a worker process: {ex}"}
    row, alive = attempt(worker, task, timeout, lambda fraction: None)
    with state["lock"]:
        if alive and state["batch"] == batch:
            state["idle"].append(worker)
            worker = None
    if worker is not None:
        _close_all([worker])
    return row


def _close_clip_workers(batch):
    """On a Dask worker: close the idle clip workers of ``batch`` (the batch ended)."""
    from distributed import get_worker

    state = get_worker().__dict__.get(_STATE)
    if state is not None:
        with state["lock"]:
            if state["batch"] == batch:
                _close_all(state["idle"])


def _close_all(workers):
    while workers:
        worker = workers.pop()
        worker.close()
        try:
            os.remove(worker.log_path)
        except OSError:
            pass


def _environment(env):
    """This Dask worker's environment with ``env``: PYTHONPATH put in front, the others where unset."""
    out = dict(os.environ)
    for name, value in env.items():
        if name == "PYTHONPATH":
            out[name] = os.pathsep.join(p for p in (value, out.get(name)) if p)
        else:
            out.setdefault(name, value)
    return out
