"""The report of a clip batch (``retarget --source-file``): one row per clip (frames, seconds, reach errors,
contacts held, failure reason), as JSON with the batch's totals and as CSV with the same rows and columns.
A row's seconds are the clip's whole time in its worker (open the target file, import, retarget, save);
import_seconds the importer's part and solve_seconds the retarget's (read, plan, solve, write)."""

import csv
import io

DONE = "done"
FAILED = "failed"
SKIPPED = "skipped"

COLUMNS = ("clip", "name", "status", "reason", "action", "output", "frames", "frame_start", "frame_end", "seconds",
           "import_seconds", "solve_seconds", "reach_error_median", "reach_error_p99", "reach_error_max",
           "missed_within_reach", "contact_frames", "contact_error_median", "contact_error_max",
           "contacts_not_held")


def batch_report(rows, seconds, **extra):
    """The batch's report as a JSON-ready dict: ``extra`` items first, then totals and the rows (every row
    has every column, None where it has no value)."""
    rows = [{column: row.get(column) for column in COLUMNS} for row in rows]
    done = [row for row in rows if row["status"] == DONE]
    frames = sum(row["frames"] or 0 for row in done)
    report = dict(extra)
    report.update({
        "seconds": float(seconds),
        "clips": {"total": len(rows), DONE: len(done),
                  FAILED: sum(row["status"] == FAILED for row in rows),
                  SKIPPED: sum(row["status"] == SKIPPED for row in rows)},
        "clips_per_minute": 60.0 * len(done) / seconds if seconds > 0 else None,
        "frames": frames,
        "missed_within_reach": sum(row["missed_within_reach"] or 0 for row in done),
        "contacts_not_held": sum(row["contacts_not_held"] or 0 for row in done),
        "rows": rows,
    })
    return report


def to_csv(report):
    """The rows as CSV text (a header line of COLUMNS; empty where a value is None)."""
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in report["rows"]:
        writer.writerow({key: "" if value is None else value for key, value in row.items()})
    return out.getvalue()


def one_line(report):
    """The batch in one line, for the console."""
    clips = report["clips"]
    line = f"{clips[DONE]} of {clips['total']} clips retargeted ({report['frames']} frames) in " \
           f"{report['seconds']:.1f} s"
    if clips[SKIPPED]:
        line += f", {clips[SKIPPED]} skipped (done before)"
    if clips[FAILED]:
        line += f", {clips[FAILED]} failed"
    if report["missed_within_reach"]:
        line += f"; {report['missed_within_reach']} targets missed within reach"
    if report["contacts_not_held"]:
        line += f"; {report['contacts_not_held']} contact frames not held within reach"
    return line
