"""The JSON report of a run: reach error per effector (median, p99, max over all
frames, reachable and unreachable targets apart), penetrations after the solve, and which frames missed which
target and why.

Input is an Outcome-like set of arrays (``bridge.outcome.Outcome`` has them all): frames (F,), effectors (E
names), residuals (F,E) world distance effector -> target (NaN: no target), status and reasons (F,E) strings,
joints_inside and segments_crossing (F,) counts.
"""

import json
import math

import numpy as np

REPORT_VERSION = 1

# Solver statuses (solver/chain/fabrik.py) and the one the body solve uses for an effector without a target.
REACHED = "reached"
UNREACHABLE = "unreachable"
UNCONSTRAINED = "unconstrained"


def error_stats(errors):
    """{'count', 'median', 'p99', 'max'} of a 1-D array of reach errors (None for an empty array)."""
    errors = np.asarray(errors, dtype=np.float64).reshape(-1)
    if errors.size == 0:
        return {"count": 0, "median": None, "p99": None, "max": None}
    return {"count": int(errors.size), "median": float(np.median(errors)),
            "p99": float(np.percentile(errors, 99.0)), "max": float(errors.max())}


def task_masks(residuals, status):
    """(constrained, reachable, unreachable) boolean (F,E) masks. A task is constrained where it has a target
    (finite residual); it is unreachable where the solver found the target beyond the body's reach, and
    reachable otherwise (met or not)."""
    residuals = np.asarray(residuals, dtype=np.float64)
    status = np.asarray(status).astype(str)
    constrained = np.isfinite(residuals) & (status != UNCONSTRAINED)
    unreachable = constrained & (status == UNREACHABLE)
    return constrained, constrained & ~unreachable, unreachable


def not_met_runs(frames, effectors, residuals, status, reasons):
    """The tasks not met, as runs of consecutive frames with the same effector, status and reason:
    [{'effector', 'status', 'reason', 'frame_start', 'frame_end', 'frames', 'max_error'}], by effector then
    frame. Consecutive means adjacent rows of ``frames``; reasons that differ only in a parenthesised detail
    (e.g. the iteration count) are the same reason, and the run keeps its first frame's wording."""
    frames = np.asarray(frames, dtype=np.float64)
    residuals = np.asarray(residuals, dtype=np.float64)
    status = np.asarray(status).astype(str)
    reasons = np.asarray(reasons).astype(str)
    constrained, _, _ = task_masks(residuals, status)
    missed = constrained & (status != REACHED)
    runs = []
    for e, effector in enumerate(effectors):
        run = None
        for f in range(len(frames)):
            if not missed[f, e]:
                run = None
                continue
            key = (status[f, e], reasons[f, e].split(" (")[0])
            if run is not None and run["_key"] == key and run["_last"] == f - 1:
                run["frame_end"] = _number(frames[f])
                run["frames"] += 1
                run["max_error"] = max(run["max_error"], float(residuals[f, e]))
                run["_last"] = f
            else:
                run = {"effector": effector, "status": key[0], "reason": reasons[f, e],
                       "frame_start": _number(frames[f]), "frame_end": _number(frames[f]), "frames": 1,
                       "max_error": float(residuals[f, e]), "_key": key, "_last": f}
                runs.append(run)
    for run in runs:
        del run["_key"], run["_last"]
    return runs


def summarize(*, frames, effectors, residuals, status, seconds, reasons=None, joints_inside=None,
              segments_crossing=None, moved_bones=(), **extra):
    """The report as a JSON-ready dict (NaN/inf never appear: unknown numbers are None). ``extra`` items
    (command, file, armature, action, settings...) are put first, as given. Without ``reasons`` a task not met
    gives its status as the reason; without penetration counts 'penetrations' is None (not measured)."""
    frames = np.asarray(frames, dtype=np.float64).reshape(-1)
    residuals = np.asarray(residuals, dtype=np.float64)
    status = np.asarray(status).astype(str)
    effectors = tuple(str(e) for e in effectors)
    if residuals.shape != (len(frames), len(effectors)) or status.shape != residuals.shape:
        raise ValueError(f"residuals and status must have shape {(len(frames), len(effectors))}, "
                         f"got {residuals.shape} and {status.shape}")
    if reasons is None:
        reasons = status
    constrained, reachable, unreachable = task_masks(residuals, status)
    met = constrained & (status == REACHED)

    reach_error = {}
    for e, effector in enumerate(effectors):
        if constrained[:, e].any():
            reach_error[effector] = _split_stats(residuals[:, e], reachable[:, e], unreachable[:, e])
    reach_error["all"] = _split_stats(residuals, reachable, unreachable)

    seconds = float(seconds)
    report = dict(extra)
    report.update({
        "report_version": REPORT_VERSION,
        "frames": {"start": _number(frames.min()) if len(frames) else None,
                   "end": _number(frames.max()) if len(frames) else None, "count": int(len(frames))},
        "seconds": seconds,
        "frames_per_second": (len(frames) / seconds) if seconds > 0 else None,
        "tasks": {
            "total": int(constrained.sum()),
            "met": int(met.sum()),
            "unreachable": int(unreachable.sum()),
            "missed_within_reach": int((reachable & ~met).sum()),
            "by_status": {s: int((constrained & (status == s)).sum()) for s in sorted(set(status[constrained]))},
        },
        "reach_error": reach_error,
        "penetrations": _penetrations(frames, joints_inside, segments_crossing),
        "moved_bones": list(moved_bones),
        "not_met": not_met_runs(frames, effectors, residuals, status, reasons),
    })
    return report


def summarize_outcome(outcome, seconds, **extra):
    """summarize() of an Outcome-like object: attributes frames, effectors, residuals and status, optionally
    reasons, joints_inside, segments_crossing and moved_bones (or keyed_bones)."""
    moved = getattr(outcome, "moved_bones", None)
    moved = getattr(outcome, "keyed_bones", ()) if moved is None else moved
    return summarize(frames=outcome.frames, effectors=outcome.effectors, residuals=outcome.residuals,
                     status=outcome.status, reasons=getattr(outcome, "reasons", None),
                     joints_inside=getattr(outcome, "joints_inside", None),
                     segments_crossing=getattr(outcome, "segments_crossing", None), seconds=seconds,
                     moved_bones=moved, **extra)


def one_line(report):
    """The report in one line, for the console."""
    tasks = report["tasks"]
    frames = report["frames"]["count"]
    fps = report["frames_per_second"]
    line = (f"{frames} frame{'s' if frames != 1 else ''} in {report['seconds']:.2f} s"
            f"{f' ({fps:.1f} frames/s)' if fps else ''}: {tasks['met']} of {tasks['total']} targets met")
    if tasks["unreachable"]:
        line += f", {tasks['unreachable']} out of reach"
    if tasks["missed_within_reach"]:
        line += f", {tasks['missed_within_reach']} missed within reach"
    worst = report["reach_error"]["all"]["reachable"]["max"]
    if worst is not None:
        line += f"; largest error within reach {worst:.3g}"
    pen = report["penetrations"]
    if pen and pen["frames"]:
        line += f"; penetrations on {pen['frames']} frames"
    contacts = contacts_line(report)
    return f"{line}; {contacts}" if contacts else line


def contacts_not_held(report):
    """[(effector, frames)] of a retarget report's contacts not held on frames whose target was within reach
    ('contacts' of bridge.retarget's contact report; [] for a report without contacts)."""
    figures = (report.get("contacts") or {}).get("effectors", {}) if isinstance(report.get("contacts"), dict) else {}
    return [(e, f["not_held_frames"]) for e, f in figures.items() if f["not_held_frames"]]


def contacts_line(report):
    """The contact figures of a retarget report in a few words ('' without them)."""
    figures = report.get("contacts")
    if not isinstance(figures, dict) or not figures.get("effectors"):
        return ""
    found = figures["effectors"].values()
    sliding = [f["sliding"]["p95"] for f in found if f["sliding"]["p95"] is not None]
    errors = [f["contact_error"]["max"] for f in found if f["contact_error"]["max"] is not None]
    units = f" {figures['units']}" if figures.get("units") else ""
    return (f"contacts: {sum(f['contact_frames'] for f in found)} frames, largest contact error "
            f"{max(errors) if errors else 0.0:.3g}{units}, sliding p95 {max(sliding) if sliding else 0.0:.3g}"
            f"{units}, "
            f"{sum(f['frames_below_floor'] for f in found)} frames below the floor, "
            f"{sum(f['pops'] for f in found)} pops, "
            f"{sum(f['not_held_frames'] for f in found)} frames not held")


def to_json(report):
    """The report as JSON text (strict: a NaN that slipped in is an error, not invalid JSON)."""
    return json.dumps(report, indent=2, allow_nan=False) + "\n"


def _penetrations(frames, joints_inside, segments_crossing):
    if joints_inside is None or segments_crossing is None:
        return None
    joints_inside = np.asarray(joints_inside, dtype=np.int64).reshape(-1)
    segments_crossing = np.asarray(segments_crossing, dtype=np.int64).reshape(-1)
    penetrating = (joints_inside > 0) | (segments_crossing > 0)
    return {"joints_inside": int(joints_inside.sum()), "segments_crossing": int(segments_crossing.sum()),
            "frames": int(penetrating.sum()),
            "first_frame": _number(frames[np.argmax(penetrating)]) if penetrating.any() else None}


def _split_stats(residuals, reachable, unreachable):
    return {"reachable": error_stats(residuals[reachable]), "unreachable": error_stats(residuals[unreachable])}


def _number(value):
    """A frame number as an int when it is whole, else a float."""
    value = float(value)
    return int(value) if math.isfinite(value) and value.is_integer() else value
