# SPDX-License-Identifier: GPL-3.0-or-later
"""``retarget --source-file CLIP ...``: many clip files onto one target character, in parallel worker
processes (``pool``; each runs ``worker``). Everything the batch can check is checked before a worker
starts (one line, exit 2, nothing written); afterwards a clip that fails is a row of the report with its reason,
the others go on, and the exit code is 1.

With --scheduler the clips go to a Dask cluster's workers instead (``cluster``), each running the same worker.

Outputs: with --output-dir, one file per clip saved by its worker: the target file with that clip's action, or
with --format fbx|glb the target and its new action through Blender's exporter (bridge.retarget.export);
else every clip's action is merged into the target file and saved as --output (or over the input with
--overwrite): each worker writes its action into a small part file, appended here as the clip ends. An
interrupted batch keeps the clips done; --skip-existing leaves them out of the next run.
"""

import glob
import os
import sys
import tempfile
import time

import bpy

from ..bridge import files as batch
from ..bridge.retarget import clip_import, export, root_motion
from ..reporting import batch_report, summary
from ..reporting.progress import ConsoleProgress, NoProgress
from .cluster import PYTHON, ClusterError, DaskPool, connect
from .files import CommandError, check_writable, checked_outputs, input_path, same_file, write_text
from .parser import COMMAND, EXIT_OK, EXIT_TARGETS_MISSED
from .pool import WorkerPool
from .retarget import retarget_target, root_smoothing

WORKER_FLAG = "--clip-worker"
SAVE_EVERY = 10.0  # seconds: while a batch runs, the merged file is saved as clips end, at most this often


def run(args):
    blend_in = input_path(args)
    clips = clip_paths(args.source_file)
    saved, csv_path = _checked_outputs(args, blend_in, clips)
    if not same_file(blend_in, batch.current_file()):
        batch.open_blend(blend_in)
    target, _contacts = retarget_target(args, bpy.context)
    if not args.output_dir:  # the clips' actions key a root bone the workers create: the merged file needs it too
        contacts = _job(args, blend_in, target.name)["contacts"]  # where the workers put it: their floor
        root_motion.add_requested_bone(bpy.context, target, args.root_motion, args.root_bone,
                                       _floor(args.floor, contacts) if ["ground", None] in contacts else None)
    rows, tasks = _tasks(args, clips)
    client = _client(args) if tasks else None
    if args.output_dir:
        os.makedirs(args.output_dir, exist_ok=True)
    jobs = min(args.jobs or os.cpu_count() or 1, max(len(tasks), 1))

    started = time.perf_counter()
    try:
        if client is not None:
            jobs = sum(client.nthreads().values())
        rows += _run_tasks(args, tasks, jobs, blend_in, target.name, saved, client)
    finally:
        if client is not None:
            client.close()
    if saved is not None:
        batch.save_blend(saved)
    order = {clip: i for i, clip in enumerate(clips)}
    rows.sort(key=lambda row: order[row["clip"]])
    report = batch_report.batch_report(rows, time.perf_counter() - started, command="retarget",
                                       file=os.path.abspath(blend_in), target=target.name, jobs=jobs,
                                       blender=bpy.app.version_string,
                                       options=_report_options(_job(args, blend_in, target.name)))
    if args.report:
        write_text(args.report, summary.to_json(report))
        write_text(csv_path, batch_report.to_csv(report))

    line = f"retarget onto '{target.name}': {batch_report.one_line(report)}"
    if args.output_dir:
        line += f"; saved in {args.output_dir}"
    else:
        line += f"; saved {saved}" if saved else "; not saved (no --output)"
    print(line)
    failed = [row for row in rows if row["status"] == batch_report.FAILED]
    for row in failed:
        print(f"{COMMAND} retarget: {os.path.basename(row['clip'])} failed: {row['reason']}", file=sys.stderr)
    missed = report["missed_within_reach"] or report["contacts_not_held"]  # as the single retarget's exit code
    return EXIT_TARGETS_MISSED if failed or missed else EXIT_OK


def _checked_outputs(args, input_path, clips):
    """Check the options and every output before anything runs: (the .blend to save the merged actions to, or
    None; the CSV report's path, or None)."""
    if args.preview:
        raise CommandError("--preview draws one retarget: leave it out with --source-file")
    if args.new_action and len(clips) > 1:
        raise CommandError("--new-action names one action: with several clips each is named after its clip")
    if args.output_dir and (args.output or args.overwrite):
        raise CommandError("--output-dir writes one file per clip: leave out --output and --overwrite")
    if args.format != "blend" and not args.output_dir:
        raise CommandError(f"--format {args.format} writes one file per clip: give --output-dir")
    if args.armature_only and args.format == "blend":
        raise CommandError("--armature-only leaves the meshes out of --format fbx or glb: give one of them")
    if args.scheduler and args.jobs:
        raise CommandError("--jobs sets the local workers: leave it out with --scheduler (the cluster's workers "
                           "run the clips)")
    if args.clip_fps == "clip" and not args.output_dir:
        raise CommandError("--clip-fps clip changes the scene's frame rate per clip: use it with --output-dir")
    saved = None if args.output_dir else checked_outputs(args, input_path)
    if args.output_dir:
        _check_output_dir(args.output_dir)
    elif args.scheduler:
        shared = os.path.dirname(os.path.abspath(saved or input_path))
        if not os.access(shared, os.W_OK | os.X_OK):
            raise CommandError(f"--scheduler: the workers write their clips' part files beside "
                               f"{'--output' if saved else 'the input file'}, and folder {shared} is not writable")
    csv_path = os.path.splitext(args.report)[0] + ".csv" if args.report else None
    if csv_path:
        check_writable(csv_path, "--report")
    return saved, csv_path


def _tasks(args, clips):
    """(rows of the clips left out by --skip-existing, tasks of the others)."""
    rows, tasks = [], []
    for clip in clips:
        name = args.new_action or os.path.splitext(os.path.basename(clip))[0]
        if args.take and not args.new_action:
            name = f"{name}_{args.take}"  # one file's takes retargeted one after another keep apart
        out = os.path.join(os.path.abspath(args.output_dir), export.output_name(name, args.format)) \
            if args.output_dir else None
        done_before = os.path.exists(out) if out else name in bpy.data.actions
        if args.skip_existing and done_before:
            rows.append({"clip": clip, "name": name, "status": batch_report.SKIPPED, "output": out,
                         "action": name})
        else:
            tasks.append({"clip": clip, "name": name, "out": out, "size": _file_size(clip)})
    return rows, tasks


def _file_size(path):
    try:
        return os.path.getsize(path)
    except OSError:  # gone since it was listed: its worker says so
        return 0


def _client(args):
    """The Dask client of --scheduler (None without it); CommandError when it cannot be had."""
    if not args.scheduler:
        return None
    try:
        return connect(args.scheduler)
    except ClusterError as ex:
        raise CommandError(str(ex)) from None


def _run_tasks(args, tasks, jobs, blend_in, target_name, saved, client=None):
    """The rows of ``tasks``, run by ``jobs`` local workers, or by the Dask cluster of ``client``. Without
    --output-dir each done clip's action is appended to the open file as it ends, and the file saved as ``saved``
    as clips end, at most once every SAVE_EVERY seconds. An interrupt (Ctrl+C) keeps what was done: the clips
    not ended by then are failed rows ('interrupted')."""
    if not tasks:
        return []
    progress = NoProgress() if args.quiet else ConsoleProgress(
        len(tasks), f"retarget {len(tasks)} clips -> '{target_name}'", unit="clips", per_minute=True)

    def show(done, failed, fraction):
        progress(f"{done}/{len(tasks)}" + (f" ({failed} failed)" if failed else ""), fraction)

    ended = {}
    last_save = [time.perf_counter()]

    def merge(index, row):  # in this thread, as each clip ends
        task = tasks[index]
        ended[index] = row
        row.setdefault("name", task["name"])
        if row["status"] != batch_report.DONE:
            return
        if task["out"]:
            row["output"] = task["out"]
            return
        row["action"] = batch.append_datablocks(bpy.context, task["part"])[row["action"]].name
        row["output"] = os.path.abspath(saved) if saved else None
        if saved and time.perf_counter() - last_save[0] >= SAVE_EVERY:
            batch.save_blend(saved)
            last_save[0] = time.perf_counter()

    # A cluster's workers write the parts where they see them: beside the saved file (or the input).
    shared = os.path.dirname(os.path.abspath(saved or blend_in)) if client is not None else None
    with tempfile.TemporaryDirectory(prefix="fba-parts-", dir=shared) as parts:
        for index, task in enumerate(tasks):
            if task["out"] is None:
                task["part"] = os.path.join(parts, f"{index}.blend")
        job = _job(args, blend_in, target_name)
        if client is None:
            pool = WorkerPool(worker_command(), job, jobs, env=worker_env(), on_progress=show,
                              timeout=args.clip_timeout)
        else:
            pool = DaskPool(client, cluster_worker_command(), job, env=cluster_worker_env(), on_progress=show,
                            timeout=args.clip_timeout)
        try:
            pool.run(tasks, on_row=merge)
        except KeyboardInterrupt:
            print(f"{COMMAND} retarget: interrupted; what was done is kept: run again with --skip-existing "
                  f"to finish", file=sys.stderr)
        progress.finish()
    return [ended.get(index) or {"clip": task["clip"], "name": task["name"], "status": batch_report.FAILED,
                                 "reason": "interrupted before it ended"} for index, task in enumerate(tasks)]


def clip_paths(patterns):
    """Absolute paths of the clips that ``patterns`` name: files, folders (their clip files) and globs,
    each clip once, in the order given (a folder's or glob's clips sorted). CommandError when a pattern names no
    clip or two clips have the same name."""
    paths = []
    for pattern in patterns:
        if os.path.isdir(pattern):
            found = sorted(os.path.join(pattern, name) for name in os.listdir(pattern)
                           if os.path.splitext(name)[1].lower() in clip_import.FORMATS)
        elif os.path.isfile(pattern):
            if os.path.splitext(pattern)[1].lower() not in clip_import.FORMATS:
                raise CommandError(f"--source-file {pattern}: not a clip file (use {clip_import.FORMAT_NAMES})")
            found = [pattern]
        else:
            found = sorted(p for p in glob.glob(pattern) if os.path.splitext(p)[1].lower() in clip_import.FORMATS)
        if not found:
            raise CommandError(f"--source-file {pattern}: no such file, or no {clip_import.FORMAT_NAMES} file there")
        paths.extend(os.path.abspath(p) for p in found)
    unique = list(dict.fromkeys(paths))
    names = {}
    for path in unique:
        name = os.path.splitext(os.path.basename(path))[0]
        if name in names:
            raise CommandError(f"two clips are named '{name}' ({names[name]} and {path}): their actions and files "
                               f"would collide")
        names[name] = path
    return unique


def _check_output_dir(folder):
    """The folder exists and is writable, or can be made (made only once the batch starts)."""
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise CommandError(f"--output-dir {folder} is a file, not a folder")
    existing = folder if os.path.isdir(folder) else os.path.dirname(os.path.abspath(folder))
    if not os.path.isdir(existing):
        raise CommandError(f"--output-dir {folder}: folder {existing} does not exist")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise CommandError(f"--output-dir {folder}: folder {existing} is not writable")


def _job(args, input_path, target):
    contacts = [list(contact) for contact in args.contacts or [("ground", None)]]
    return {"file": os.path.abspath(input_path), "target": target,
            "import": {"scale": args.clip_scale, "forward": args.clip_forward, "up": args.clip_up,
                       "fps": args.clip_fps, "start_frame": args.clip_start_frame, "take": args.take},
            "contacts": contacts,
            "floor": _floor(args.floor, contacts), "frame_start": args.frame_start,
            "frame_end": args.frame_end, "keep_sources": args.keep_sources, "format": args.format,
            "meshes": not args.armature_only, "mirror": args.mirror, "groups": args.groups,
            "root_motion": args.root_motion, "root_bone": args.root_bone, "root_smoothing": args.root_smoothing}


# What of a job shapes its clips' results, as the report states it.
_SHAPING = ("import", "contacts", "floor", "frame_start", "frame_end", "mirror", "groups", "root_motion", "root_bone",
            "root_smoothing", "format", "meshes")


def _report_options(job):
    """The job's options that shape the results, with the root smoothing the workers use where it is defaulted."""
    options = {key: job[key] for key in _SHAPING}
    options["root_smoothing"] = root_smoothing(options["root_motion"], options["root_smoothing"])
    return options


def _floor(floor, contacts):
    """A clip's floor: as given; by default 0 when the ground is a contact (a clip's own ground is wherever its
    capture put it), else the clip's own (it must meet its objects where they are)."""
    if floor is not None:
        return floor
    return 0.0 if ["ground", None] in contacts else None


# --- the worker processes ---------------------------------------------------------------------------------------

def _package():
    """(folder holding the package, the package's name): what a fresh process imports it as (this file is in
    the package's cli/)."""
    real = os.path.realpath(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return os.path.dirname(real), os.path.basename(real)


def worker_command(binary=None):
    """How to start a worker: under Blender (``binary``, default: this one), the same Blender in the background
    without the user's settings, running worker_code(); with the bpy module, the same Python."""
    binary = bpy.app.binary_path if binary is None else binary
    if binary and os.path.basename(binary).lower().startswith("blender"):
        return [binary, "-b", "--factory-startup", "--python-expr", worker_code()]
    return [sys.executable, "-m", _package()[1], WORKER_FLAG]


def cluster_worker_command():
    """A clip worker on a Dask worker: its own Python (cluster.PYTHON) with the bpy module, as --jobs starts it
    with the bpy module."""
    return [PYTHON, "-m", _package()[1], WORKER_FLAG]


def cluster_worker_env():
    """What a Dask worker adds to its environment for its clip workers: this package's folder in front of its
    PYTHONPATH (on shared storage, or the worker's own copy is found), OpenBLAS on one thread where unset."""
    return {"PYTHONPATH": _package()[0], "OPENBLAS_NUM_THREADS": "1"}


def worker_code():
    """The Python a Blender worker runs: this package imported from its folder, then its worker loop."""
    parent, name = _package()
    return f"import sys; sys.path.insert(0, {parent!r}); from {name}.__main__ import worker; worker()"


def worker_env():
    """The workers' environment: this package importable, and numpy's OpenBLAS on one thread unless the user
    says otherwise (the workers are the parallelism; OpenBLAS's own threads spin between calls and took a
    quarter of a worker's CPU time, measured with bench/batch_many.py's clips)."""
    parent, _name = _package()
    env = dict(os.environ)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (parent, env.get("PYTHONPATH")) if p)
    return env
