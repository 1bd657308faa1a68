# SPDX-License-Identifier: GPL-3.0-or-later
"""Running clips in parallel worker processes (no bpy here: it only starts processes and talks to them).

Each worker is a Python with bpy or a `blender -b` started with ``command``; it reads a job (one JSON line) on
stdin, then one task (a JSON line) at a time, and answers on stdout with JSON lines: ``{"progress": f}`` while it
works and ``{"row": {...}}`` when the task is done (its chatter goes to stderr, kept in a log file). A worker takes
the next task as soon as it is free, the largest first (a task's "size", e.g. its file's bytes), so the batch does
not end waiting on one long clip. A worker that dies fails only the task it had, with the last line it wrote as the
reason, and a fresh worker takes the rest; so does a worker stopped because its task ran longer than the pool's
timeout.
"""

from collections import deque
import json
import os
import queue
import subprocess
import tempfile
import threading

from ..reporting.batch_report import FAILED


class WorkerPool:
    """``jobs`` workers started with ``command`` (argv list) and ``env``; ``job`` is sent to each first.
    ``on_progress(done, failed, fraction)`` is called (from worker threads, one at a time) as tasks go on; it
    must not touch Blender data (on_row of ``run`` may). ``timeout``: seconds a task may run before its worker
    is stopped and the task fails (None: no limit)."""

    def __init__(self, command, job, jobs, *, env=None, on_progress=None, timeout=None):
        self.command = list(command)
        self.job = job
        self.jobs = max(1, int(jobs))
        self.env = env
        self.timeout = timeout
        self.on_progress = on_progress or (lambda done, failed, fraction: None)
        self._lock = threading.Lock()

    def run(self, tasks, on_row=None):
        """The row of every task (dicts, in the order given; a task is a dict with at least 'clip', started
        largest 'size' first, ties in the order given).
        ``on_row(index, row)`` is called in the calling thread as each task ends. On KeyboardInterrupt no task
        is started any more and the interrupt goes on to the caller (workers end after their task)."""
        tasks = list(tasks)
        self._queue = deque(sorted(enumerate(tasks), key=lambda item: -item[1].get("size", 0)))
        self._ended = queue.SimpleQueue()
        self._share = {}  # task index -> fraction done of a running task
        self._done = self._failed = 0
        self._total = len(tasks)
        rows = [None] * len(tasks)
        with tempfile.TemporaryDirectory(prefix="fba-workers-") as logs:
            threads = [threading.Thread(target=self._serve, args=(os.path.join(logs, f"worker{i}.log"),),
                                        daemon=True) for i in range(min(self.jobs, len(tasks)))]
            for thread in threads:
                thread.start()
            try:
                for _ in tasks:
                    index, row = self._ended.get()
                    rows[index] = row
                    if on_row is not None:
                        on_row(index, row)
            except BaseException:
                with self._lock:
                    self._queue.clear()
                raise
            for thread in threads:
                thread.join()
        return rows

    def _next(self):
        with self._lock:
            return self._queue.popleft() if self._queue else None

    def _serve(self, log_path):
        worker = None
        try:
            while (item := self._next()) is not None:
                index, task = item
                if worker is None:
                    try:
                        worker = _Worker(self.command, self.env, log_path, self.job)
                    except OSError as ex:  # e.g. the program is gone: every task says so
                        self._finish(index, {"clip": task["clip"], "status": FAILED,
                                             "reason": f"cannot start a worker process: {ex}"})
                        continue
                row, alive = attempt(worker, task, self.timeout,
                                     lambda fraction, i=index: self._progress(i, fraction))
                if not alive:  # the worker died: this task failed, a new worker takes the next one
                    worker = None
                self._finish(index, row)
        finally:
            if worker is not None:
                worker.close()

    def _progress(self, index, fraction):
        with self._lock:
            self._share[index] = fraction
            self._report()

    def _finish(self, index, row):
        self._ended.put((index, row))
        with self._lock:
            self._share.pop(index, None)
            self._done += 1
            self._failed += row.get("status") == FAILED
            self._report()

    def _report(self):
        fraction = (self._done + sum(self._share.values())) / max(self._total, 1)
        self.on_progress(self._done, self._failed, fraction)


def attempt(worker, task, timeout, progress):
    """(row, whether ``worker`` lives on) of ``task`` run by ``worker`` (a _Worker), stopped after ``timeout``
    seconds (None: no limit). A worker that died is closed, and its task a failed row saying why. Also what a
    Dask worker runs (cli.cluster): it must use nothing of this package but this module's _Worker."""
    watchdog = None
    if timeout is not None:
        watchdog = threading.Timer(timeout, worker.stop)
        watchdog.start()
    row = worker.do(task, progress)
    if watchdog is not None:
        watchdog.cancel()
    if row is not None:
        return row, True
    reason = f"stopped after {timeout:g} s (the clip time limit)" if worker.stopped else worker.death()
    worker.close()
    return {"clip": task["clip"], "status": FAILED, "reason": reason}, False


class _Worker:
    def __init__(self, command, env, log_path, job):
        self.log_path = log_path
        self.log = open(log_path, "ab")
        self.process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log,
                                        env=env, text=True, bufsize=1)
        self.stopped = False
        self._closed = False
        self._send(job)

    def stop(self):
        """Kill the process (from the pool's watchdog thread): its task then ends without a row."""
        self.stopped = True
        self.process.kill()

    def do(self, task, progress):
        """The task's row, or None when the worker died before it answered."""
        if not self._send(task):
            return None
        for line in self.process.stdout:
            try:
                message = json.loads(line)
            except ValueError:
                continue  # not ours: a stray line on the protocol stream is skipped
            if "progress" in message:
                progress(float(message["progress"]))
            elif "row" in message:
                return message["row"]
        return None

    def death(self):
        """Why the worker stopped: its exit code and the last line it wrote."""
        self.close()
        code = self.process.returncode
        try:
            with open(self.log_path, "rb") as log:
                lines = [ln.strip() for ln in log.read().decode("utf-8", "replace").splitlines() if ln.strip()]
        except OSError:
            lines = []
        last = f": {lines[-1][:200]}" if lines else ""
        return f"worker process stopped (exit code {code}){last}"

    def close(self):
        if self._closed:
            return
        self._closed = True
        try:
            self.process.stdin.close()
        except OSError:
            pass
        try:
            self.process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        self.process.stdout.close()
        self.log.close()

    def _send(self, message):
        try:
            self.process.stdin.write(json.dumps(message) + "\n")
            self.process.stdin.flush()
        except OSError:  # BrokenPipeError: it is gone
            return False
        return True
