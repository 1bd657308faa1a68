# SPDX-License-Identifier: GPL-3.0-or-later
"""One worker process of a clip batch (``retarget --source-file``; the pool is ``pool``): for each task,
open the target's .blend, import the clip, retarget it onto the target, and write the result, then answer with
the clip's row. A clip that fails is a row with its reason; the worker goes on with the next one.

The job (first line on stdin): file, target, import (clip_import.ImportOptions fields), contacts (pairs
[kind, object name or null]), floor, frame_start, frame_end, keep_sources, format and meshes (of the files
written to --output-dir: bridge.retarget.export), watch_parent (a Dask worker's clip worker: it ends with the
process that started it). A task: clip, name (of the action), out (the file to write, one
per clip) or part (a small .blend holding only the new action, merged by the parent).
"""

import json
import os
import sys
import threading
import time
import traceback

import bpy
import numpy as np

from ..bridge import files as batch
from ..bridge.retarget import clip_import, export
from ..bridge.errors import AdjustError
from ..bridge.retarget.run import retarget
from ..reporting import summary
from ..reporting.batch_report import DONE, FAILED


def serve():
    """Answer tasks until stdin ends. The protocol goes to the process's original stdout; everything else
    printed (importers, Blender) goes to stderr, so it cannot break a message."""
    protocol = os.fdopen(os.dup(1), "w", buffering=1)
    sys.stdout.flush()
    os.dup2(2, 1)
    job = json.loads(sys.stdin.readline())
    if job.get("watch_parent"):
        _end_with_parent()

    def send(message):
        protocol.write(json.dumps(message) + "\n")

    for line in sys.stdin:
        if line.strip():
            task = json.loads(line)
            send({"row": retarget_task(bpy.context, job, task, lambda f: send({"progress": f}))})
    protocol.close()


def _end_with_parent(every=0.5):
    """End this process as soon as the process that started it is gone (a Dask worker killed mid-clip: the clip
    is retried elsewhere, and this one must not write its output too)."""
    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(every)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def retarget_task(context, job, task, progress=lambda fraction: None):
    """The row of one task (see the module docstring); never raises."""
    started = time.perf_counter()
    row = {"clip": task["clip"], "name": task["name"]}
    try:
        row.update(_retarget_clip(context, job, task, progress))
        row["status"] = DONE
    except AdjustError as ex:
        row.update(status=FAILED, reason=str(ex))
    except Exception as ex:  # a bug or an importer's surprise: this clip fails, the batch goes on
        where = traceback.extract_tb(ex.__traceback__)[-1]
        row.update(status=FAILED, reason=f"internal error: {type(ex).__name__}: {' '.join(str(ex).split())} "
                                         f"({os.path.basename(where.filename)}:{where.lineno})")
    row["seconds"] = time.perf_counter() - started
    return row


def _retarget_clip(context, job, task, progress):
    batch.open_blend(job["file"])
    target = batch.armature_named(context, job["target"], "--target")
    progress(0.05)
    import_started = time.perf_counter()
    source, added = clip_import.import_clip(context, task["clip"], clip_import.ImportOptions(**job["import"]))
    import_seconds = time.perf_counter() - import_started
    progress(0.3)
    start, end = batch.frame_range(source, context.scene, job.get("frame_start"), job.get("frame_end"))
    batch.check_frame_budget(context, target, start, end)
    solve_started = time.perf_counter()
    outcome = retarget(context, source, target, start, end, contacts=job.get("contacts", [["ground", None]]),
                       floor=job.get("floor"), root_motion=job.get("root_motion"), root_bone=job.get("root_bone"),
                       root_smoothing=job.get("root_smoothing"),
                       new_action=task["name"], mirror=job.get("mirror", False), groups=job.get("groups"),
                       progress=lambda stage, fraction: progress(0.3 + 0.6 * fraction))
    solve_seconds = time.perf_counter() - solve_started
    if not job.get("keep_sources"):
        clip_import.remove_ids(added)
    if task.get("out"):
        export.write_clip(context, target, outcome.action, task["out"], job.get("format", "blend"),
                          meshes=job.get("meshes", True))
    else:
        kept = [ob for ob in added if isinstance(ob, bpy.types.Object)] if job.get("keep_sources") else []
        batch.write_datablocks(task["part"], [outcome.action, *kept])
    progress(1.0)
    return dict(clip_row(outcome, solve_seconds), import_seconds=import_seconds)


def clip_row(outcome, solve_seconds):
    """A clip's figures: frames, retarget time (read, plan, solve, write), reach error within reach, contact
    frames held, their error as the result keeps the source's contacts (the retarget's contact report, as the
    single command reports it), and the contact frames within reach not held."""
    report = summary.summarize_outcome(outcome, solve_seconds)
    reach = report["reach_error"]["all"]["reachable"]
    held = np.asarray(outcome.contacts, dtype=bool)
    measured = np.asarray(outcome.contact_error, dtype=np.float64) if outcome.contact_error is not None \
        else np.full(held.shape, np.nan)
    contact_errors = measured[np.isfinite(measured)]
    return {
        "action": outcome.action.name,
        "frames": report["frames"]["count"],
        "frame_start": report["frames"]["start"],
        "frame_end": report["frames"]["end"],
        "solve_seconds": solve_seconds,
        "reach_error_median": reach["median"],
        "reach_error_p99": reach["p99"],
        "reach_error_max": reach["max"],
        "missed_within_reach": report["tasks"]["missed_within_reach"],
        "contact_frames": int(held.sum()),
        "contact_error_median": float(np.median(contact_errors)) if contact_errors.size else None,
        "contact_error_max": float(contact_errors.max()) if contact_errors.size else None,
        "contacts_not_held": int(outcome.contacts_not_held()),
    }
