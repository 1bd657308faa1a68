"""The worker pool of a clip batch (fullbody_adjust.cli.pool) and the batch's report, without Blender: the
workers here are small Python scripts speaking the same protocol."""

import csv
import io
import json
import sys
import threading
import time

import pytest

from fullbody_adjust.cli.pool import WorkerPool
from fullbody_adjust.reporting import batch_report, summary

# A worker: answers each task with a row naming its process, after some chatter and a progress message; the task
# 'crash' makes it die with exit code 7 after a last word on stderr.
FAKE_WORKER = r"""
import json, os, sys
job = json.loads(sys.stdin.readline())
for line in sys.stdin:
    task = json.loads(line)
    if task["clip"] == "crash":
        print("about to crash", file=sys.stderr, flush=True)
        os._exit(7)
    print("chatter that is not a message")
    print(json.dumps({"progress": 0.5}), flush=True)
    print(json.dumps({"row": {"clip": task["clip"], "status": "done", "pid": os.getpid(), "tag": job["tag"]}}),
          flush=True)
"""


def test_a_dying_worker_fails_only_its_task_and_a_new_one_takes_the_rest():
    seen = []
    pool = WorkerPool([sys.executable, "-c", FAKE_WORKER], {"tag": "job-1"}, 2,
                      on_progress=lambda done, failed, fraction: seen.append((done, failed, fraction)))
    clips = ["a", "crash", "b", "c", "crash", "d"]
    rows = pool.run({"clip": clip} for clip in clips)
    assert [row["clip"] for row in rows] == clips  # in the order given
    for row in rows:
        if row["clip"] == "crash":
            assert row["status"] == "failed" and row["reason"] == (
                "worker process stopped (exit code 7): about to crash")
        else:
            assert row["status"] == "done" and row["tag"] == "job-1"  # every worker got the job first
    assert len({row["pid"] for row in rows if "pid" in row}) <= 2 + 2  # two workers, one more per crash
    assert seen[-1] == (6, 2, 1.0)
    assert [s[0] for s in seen] == sorted(s[0] for s in seen)  # done only grows
    assert all(0.0 <= s[2] <= 1.0 for s in seen)


# A worker whose task 'hang' never ends.
HANGING_WORKER = FAKE_WORKER.replace('    if task["clip"] == "crash":',
                                     '    if task["clip"] == "hang":\n        import time\n        time.sleep(3600)\n'
                                     '    if task["clip"] == "crash":')


def test_a_clip_over_the_time_limit_fails_and_the_batch_goes_on():
    pool = WorkerPool([sys.executable, "-c", HANGING_WORKER], {"tag": "t"}, 2, timeout=1.5)
    start = time.monotonic()
    rows = pool.run({"clip": clip} for clip in ["a", "hang", "b", "c", "hang", "d"])
    assert time.monotonic() - start < 30.0  # not an hour
    for row in rows:
        if row["clip"] == "hang":
            assert row["status"] == "failed" and row["reason"] == "stopped after 1.5 s (the clip time limit)"
        else:
            assert row["status"] == "done"
    # Without a limit the same workers answer every other clip as before.
    rows = WorkerPool([sys.executable, "-c", HANGING_WORKER], {"tag": "t"}, 2).run({"clip": c} for c in "ab")
    assert [row["status"] for row in rows] == ["done", "done"]


def test_rows_reach_the_caller_in_its_thread_and_an_interrupt_starts_no_more_tasks():
    calls = []

    def on_row(index, row):
        calls.append((index, row["clip"], threading.current_thread() is threading.main_thread()))
        raise KeyboardInterrupt

    pool = WorkerPool([sys.executable, "-c", FAKE_WORKER], {"tag": "t"}, 1)
    with pytest.raises(KeyboardInterrupt):
        pool.run([{"clip": c} for c in "abcd"], on_row=on_row)
    assert calls == [(0, "a", True)]
    assert not pool._queue  # nothing left to start


def test_the_largest_tasks_start_first_and_rows_keep_the_order_given():
    started = []
    pool = WorkerPool([sys.executable, "-c", FAKE_WORKER], {"tag": "t"}, 1)
    tasks = [{"clip": "a", "size": 10}, {"clip": "b", "size": 300}, {"clip": "c"}, {"clip": "d", "size": 40},
             {"clip": "e", "size": 40}]
    rows = pool.run(tasks, on_row=lambda index, row: started.append(row["clip"]))
    assert started == ["b", "d", "e", "a", "c"]  # one worker: it ends them in the order it starts them
    assert [row["clip"] for row in rows] == ["a", "b", "c", "d", "e"]


def test_a_worker_that_cannot_start_fails_every_task_with_the_reason(tmp_path):
    rows = WorkerPool([str(tmp_path / "no-such-program")], {}, 2).run([{"clip": "a"}, {"clip": "b"}])
    assert [row["status"] for row in rows] == ["failed", "failed"]
    assert all(row["reason"].startswith("cannot start a worker process: ") for row in rows)


def test_the_batch_report_counts_its_rows_and_the_csv_holds_them():
    rows = [{"clip": "/c/a.bvh", "name": "a", "status": "done", "frames": 300, "seconds": 1.5,
             "missed_within_reach": 2, "contact_error_max": 1e-7},
            {"clip": "/c/b.bvh", "name": "b", "status": "failed", "reason": "Cannot import b.bvh: bad, \"quoted\""},
            {"clip": "/c/c.bvh", "name": "c", "status": "skipped"},
            {"clip": "/c/d.bvh", "name": "d", "status": "done", "frames": 120, "missed_within_reach": 0,
             "contacts_not_held": 3}]
    report = batch_report.batch_report(rows, 30.0, target="Hero")
    assert report["target"] == "Hero"
    assert report["clips"] == {"total": 4, "done": 2, "failed": 1, "skipped": 1}
    assert report["frames"] == 420 and report["missed_within_reach"] == 2 and report["contacts_not_held"] == 3
    assert report["clips_per_minute"] == pytest.approx(60.0 * 2 / 30.0)
    assert all(set(row) == set(batch_report.COLUMNS) for row in report["rows"])
    json.loads(summary.to_json(report))
    listed = list(csv.DictReader(io.StringIO(batch_report.to_csv(report))))
    assert [r["name"] for r in listed] == ["a", "b", "c", "d"]
    assert listed[1]["reason"] == rows[1]["reason"] and listed[1]["frames"] == ""
    assert float(listed[0]["contact_error_max"]) == 1e-7
    line = batch_report.one_line(report)
    assert "2 of 4 clips" in line and "1 skipped" in line and "1 failed" in line and "2 targets missed" in line \
        and "3 contact frames not held" in line
