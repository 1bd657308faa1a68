# SPDX-License-Identifier: GPL-3.0-or-later
"""The command line: ``blender -b FILE.blend -c fullbody_adjust SUBCOMMAND ...`` (registered with
``bpy.utils.register_cli_command``) and, with the bpy wheel, ``python -m fullbody_adjust SUBCOMMAND FILE.blend
...`` (``__main__.py``). Both end in ``main(argv)``, which returns the exit code.

Thin: the arguments are ``cli_parser``'s, a batch of clip files (``retarget --source-file``) is
``cli_clips``'s; the work is ``bridge.adjustment.adjust_frames`` and ``bridge.retarget.retarget``, the
Blender-side chores (open, save, pick the armature and the frames, read the preview's skeletons) are in
``bridge.batch``, the report, progress line and picture in ``reporting``. Every expected problem — bad
arguments, a missing file, an unknown armature, a frame range outside the action, a rig that cannot be mapped,
an unwritable output — ends the run with one line on stderr, a non-zero exit code and no file written; the
input .blend is only ever written with --overwrite.
"""

from dataclasses import dataclass
import os
import sys
import time
import traceback

import bpy
import numpy as np

from .bridge import adjustment, batch, start_checks
from .bridge.retarget import retarget as retarget_motion
from .bridge.errors import AdjustError
from .reporting import preview, summary
from .reporting.progress import ConsoleProgress, NoProgress
from .cli_parser import (COMMAND, EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_OK, EXIT_TARGETS_MISSED, _VARIANTS,
                         _ParserExit, _UsageError, build_parser)

__all__ = ("COMMAND", "CommandError", "build_parser", "check_writable", "checked_outputs", "input_path", "main",
           "register", "same_file", "unregister", "write_text")


class CommandError(Exception):
    """A problem with the arguments or the input: exit 2 with this one line."""


def main(argv, prog=f"blender -b FILE.blend -c {COMMAND}"):
    """Run the command line ``argv`` (the arguments after the command id); returns the exit code."""
    parser = build_parser(prog)
    try:
        args = parser.parse_args(list(argv))
    except _ParserExit as ex:
        return ex.status
    except _UsageError as ex:
        print(str(ex), file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.subcommand is None:
        print(f"{prog}: error: choose a subcommand: adjust or retarget (see --help)", file=sys.stderr)
        return EXIT_BAD_INPUT
    where = f"{COMMAND} {args.subcommand}"
    try:
        if getattr(args, "source_file", None):
            from . import cli_clips  # the batch of clip files: worker processes, one row per clip
            return cli_clips.run(args)
        return _execute(args)
    except (CommandError, AdjustError) as ex:
        print(f"{where}: error: {_one_line(ex)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as ex:  # a bug: still one line (and the traceback on request), never a Blender crash
        if args.debug:
            traceback.print_exc()
        print(f"{where}: internal error: {type(ex).__name__}: {_one_line(ex)} (a bug; --debug shows where)",
              file=sys.stderr)
        return EXIT_INTERNAL


# --- a run -----------------------------------------------------------------------------------------------------

@dataclass
class WorkResult:
    """What a subcommand's work hands back: an Outcome-like result (see reporting.summary), the solve's
    seconds, the preview's data (None without --preview) and items for the report's header."""

    outcome: object
    seconds: float
    figure: object
    details: dict


def _execute(args):
    blend_in = input_path(args)
    saved = checked_outputs(args, blend_in)
    if not same_file(blend_in, batch.current_file()):
        batch.open_blend(blend_in)
    result = _WORK[args.work](args, bpy.context)

    report = summary.summarize_outcome(
        result.outcome, result.seconds, command=args.subcommand, file=os.path.abspath(blend_in),
        output=os.path.abspath(saved) if saved else None, blender=bpy.app.version_string, **result.details)
    if saved is not None:
        batch.save_blend(saved)
    if args.report:
        write_text(args.report, summary.to_json(report))
    if args.preview:
        _write_png(args.preview, preview.render(result.figure))

    line = f"{args.subcommand} '{result.details.get('armature') or result.details.get('target')}': " \
           f"{summary.one_line(report)}"
    line += f"; saved {saved}" if saved else "; not saved (no --output)"
    print(line)
    return _exit_code(args, report)


def _exit_code(args, report):
    missed = [run for run in report["not_met"] if run["status"] != summary.UNREACHABLE]
    penetrations = report["penetrations"]
    if missed:
        run = missed[0]
        frames = (f"frame {run['frame_start']}" if run["frames"] == 1
                  else f"frames {run['frame_start']}..{run['frame_end']}")
        more = f" (and {len(missed) - 1} more, see the report)" if len(missed) > 1 else ""
        print(f"{COMMAND} {args.subcommand}: {run['effector']} missed within reach on {frames}: "
              f"{run['reason'] or run['status']}{more}", file=sys.stderr)
        return EXIT_TARGETS_MISSED
    not_held = summary.contacts_not_held(report)
    if not_held:
        effector, frames = not_held[0]
        more = f" (and {len(not_held) - 1} more, see the report)" if len(not_held) > 1 else ""
        print(f"{COMMAND} {args.subcommand}: {effector} does not hold its contact on {frames} frames within "
              f"reach{more}", file=sys.stderr)
        return EXIT_TARGETS_MISSED
    if penetrations and penetrations["frames"]:
        print(f"{COMMAND} {args.subcommand}: bones inside obstacles on {penetrations['frames']} frames (first: "
              f"{penetrations['first_frame']})", file=sys.stderr)
        return EXIT_TARGETS_MISSED
    return EXIT_OK


def input_path(args):
    if args.file is not None:
        if not os.path.exists(args.file):
            raise CommandError(f"no such file: {args.file}")
        return args.file
    if batch.current_file():
        return batch.current_file()
    raise CommandError("no .blend file: give FILE.blend")


def checked_outputs(args, input_path):
    """Check every output path before anything runs; returns the .blend path to save to (None: none)."""
    if args.output is not None:
        blend = args.output
        if same_file(blend, input_path) and not args.overwrite:
            raise CommandError(f"--output {blend} is the input file: add --overwrite to replace it")
    elif args.overwrite:
        blend = input_path
    else:
        blend = None
    named = [(blend, "--output" if args.output else "--overwrite", ".blend"), (args.report, "--report", None),
             (args.preview, "--preview", ".png")]
    seen = {}
    for path, option, suffix in named:
        if path is None:
            continue
        if suffix and not path.lower().endswith(suffix):
            raise CommandError(f"{option} {path}: the file name must end in {suffix}")
        if option != "--overwrite" and option != "--output" and same_file(path, input_path):
            raise CommandError(f"{option} {path} would overwrite the input file")
        check_writable(path, option)
        key = os.path.realpath(path)
        if key in seen:
            raise CommandError(f"{option} and {seen[key]} name the same file: {path}")
        seen[key] = option
    return blend


def check_writable(path, option):
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise CommandError(f"{option} {path} is a folder")
    if not os.path.isdir(folder):
        raise CommandError(f"{option} {path}: folder {folder} does not exist")
    if os.path.exists(path) and not os.access(path, os.W_OK):
        raise CommandError(f"{option} {path}: file is not writable")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise CommandError(f"{option} {path}: folder {folder} is not writable")


def same_file(a, b):
    if not a or not b:
        return False
    if os.path.exists(a) and os.path.exists(b):
        return os.path.samefile(a, b)
    return os.path.realpath(a) == os.path.realpath(b)


def write_text(path, text):
    try:
        with open(path, "w", encoding="utf-8") as out:
            out.write(text)
    except OSError as ex:
        raise CommandError(f"cannot write {path}: {ex.strerror}") from None


def _write_png(path, image):
    try:
        preview.write_png(path, image)
    except OSError as ex:
        raise CommandError(f"cannot write {path}: {ex.strerror}") from None


def _progress(args, frames, label):
    return NoProgress() if args.quiet else ConsoleProgress(frames, label)


# --- adjust ----------------------------------------------------------------------------------------------------

def _adjust(args, context):
    obj = (batch.armature_named(context, args.armature) if args.armature is not None
           else batch.default_armature(context))
    start_checks.check_armature(obj)
    batch.check_mappable(obj, "--armature")
    start, end = batch.frame_range(obj, context.scene, args.frame_start, args.frame_end)
    batch.check_frame_budget(context, obj, start, end)
    options = adjustment.Options(
        variant=_VARIANTS[args.variant] if args.variant else None, margin=args.margin, tolerance=args.tolerance,
        max_iterations=args.max_iterations, use_joint_limits=False if args.no_limits else None,
        new_action=args.new_action)
    settings = batch.stored_settings(obj)
    settings.update({name: value for name, value in vars(options).items() if name in settings and value is not None})
    original_action = batch.action_name(obj)

    frames = np.arange(start, end + 1, dtype=np.float64)
    shown = frames[preview.pick_snapshots(len(frames), args.preview_frames)]
    if args.preview:  # the pose before, read before anything changes
        before_segments = batch.skeleton_segments(obj, shown)
        before_effectors = batch.effector_positions(obj, frames)
        target_frames = batch.target_positions(context, obj, frames)
        boxes = batch.obstacle_extents(context, obj, shown)

    progress = _progress(args, len(frames), f"adjust '{obj.name}'")
    started = time.perf_counter()
    outcome = adjustment.adjust_frames(context, obj, start, end, options, progress=progress)
    seconds = time.perf_counter() - started
    progress.finish()

    figure = None
    if args.preview:
        figure = preview.FigureData(
            title=f"ADJUST '{obj.name}'  FRAMES {start}-{end}  {settings['variant']}",
            frames=outcome.frames, effectors=outcome.effectors, error_after=outcome.residuals,
            error_before=np.linalg.norm(before_effectors - target_frames, axis=-1),
            snapshot_frames=shown, after_segments=batch.skeleton_segments(obj, shown),
            before_segments=before_segments, targets=target_frames[np.searchsorted(frames, shown)], boxes=boxes)
    details = {"armature": obj.name, "original_action": original_action,
               "action": outcome.action.name if outcome.action is not None else batch.action_name(obj),
               "settings": settings}
    return WorkResult(outcome=outcome, seconds=seconds, figure=figure, details=details)


# --- retarget --------------------------------------------------------------------------------------------------

def retarget_target(args, context):
    """A retarget's --target armature, checked as retargeting onto it needs (one line otherwise), and its
    --contacts as the bridge takes them ('ground', or ('object', Object))."""
    target = batch.armature_named(context, args.target, "--target")
    start_checks.check_armature(target)
    batch.check_mappable(target, "--target")
    contacts = [kind if name is None else (kind, batch.object_named(context, name, "--contacts object"))
                for kind, name in args.contacts or [("ground", None)]]
    return target, contacts


def _retarget(args, context):
    source = batch.armature_named(context, args.source, "--source")
    batch.check_mappable(source, "--source")
    target, contacts = retarget_target(args, context)
    if source == target:
        raise CommandError("--source and --target are the same armature")
    start, end = batch.frame_range(source, context.scene, args.frame_start, args.frame_end, within_scene=True)
    batch.check_frame_budget(context, target, start, end)

    frames = np.arange(start, end + 1, dtype=np.float64)
    shown = frames[preview.pick_snapshots(len(frames), args.preview_frames)]
    progress = _progress(args, len(frames), f"retarget '{source.name}' -> '{target.name}'")
    started = time.perf_counter()
    outcome = retarget_motion(context, source, target, start, end, contacts=contacts, new_action=args.new_action,
                              floor=args.floor, progress=progress)
    seconds = time.perf_counter() - started
    progress.finish()

    figure = None
    if args.preview:  # the source's motion in grey, the target's in blue, with the targets the retarget set
        planned = getattr(outcome, "targets", None)  # (F,E,3) world
        figure = preview.FigureData(
            title=f"RETARGET '{source.name}' TO '{target.name}'  FRAMES {start}-{end}",
            frames=outcome.frames, effectors=outcome.effectors, error_after=outcome.contact_error,
            error_before=outcome.contact_error_before, plot_title="CONTACT ERROR (SCENE UNITS) OVER FRAMES",
            snapshot_frames=shown, before_segments=batch.skeleton_segments(source, shown),
            after_segments=batch.skeleton_segments(target, shown),
            targets=None if planned is None else planned[np.searchsorted(outcome.frames, shown)])
    action = getattr(outcome, "action", None)
    details = {"source": source.name, "target": target.name, "armature": target.name,
               "contacts": outcome.contact_report, "floor": args.floor,
               "action": action.name if action is not None else batch.action_name(target)}
    return WorkResult(outcome=outcome, seconds=seconds, figure=figure, details=details)


_WORK = {"adjust": _adjust, "retarget": _retarget}


def _one_line(ex):
    return " ".join(str(ex).split())


# --- registration ----------------------------------------------------------------------------------------------

_handle = None


def register():
    global _handle
    _handle = bpy.utils.register_cli_command(COMMAND, main)


def unregister():
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None
