# SPDX-License-Identifier: GPL-3.0-or-later
"""The command line: ``blender -b FILE.blend -c fullbody_adjust SUBCOMMAND ...`` (registered with
``bpy.utils.register_cli_command``) and, with the bpy wheel, ``python -m fullbody_adjust SUBCOMMAND FILE.blend
...`` (``__main__.py``). Both end in ``main(argv)``, which returns the exit code.

Thin: the work is ``bridge.adjustment.adjust_frames`` and ``bridge.retarget.retarget``, the
Blender-side chores (open, save, pick the armature and the frames, read the preview's skeletons) are in
``bridge.batch``, the report, progress line and picture in ``reporting``. Every expected problem — bad
arguments, a missing file, an unknown armature, a frame range outside the action, a rig that cannot be mapped,
an unwritable output — ends the run with one line on stderr, a non-zero exit code and no file written; the
input .blend is only ever written with --overwrite.
"""

import argparse
from dataclasses import dataclass
import os
import sys
import time
import traceback

import bpy
import numpy as np

from .solver.vocabulary import VARIANTS
from .bridge import adjustment, batch
from .bridge.retarget import retarget as retarget_motion
from .bridge.errors import AdjustError
from .reporting import preview, summary
from .reporting.progress import ConsoleProgress, NoProgress

COMMAND = "fullbody_adjust"

EXIT_OK = 0
EXIT_TARGETS_MISSED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 3

EXIT_CODES_HELP = """\
exit codes:
  0  done: every target within reach was met and no bone ends inside an obstacle (targets beyond the
     body's reach are stretched toward and listed in the report, but do not fail the run)
  1  done and written, but on some frame a target within reach was missed (an obstacle blocked it,
     joint limits held it, or the iterations ran out), a retarget's contact within reach was not held, or
     a bone ends inside an obstacle: see --report
  2  bad arguments or input (missing or unreadable file, unknown armature or object, frame range outside
     the action, a rig that cannot be mapped, an output that cannot be written...): one line on stderr,
     nothing written, the input file untouched
  3  internal error (a bug; --debug prints the traceback)"""

_VARIANTS = {variant: variant.upper() for variant in VARIANTS}


class CommandError(Exception):
    """A problem with the arguments or the input: exit 2 with this one line."""


class _UsageError(Exception):
    pass


class _ParserExit(Exception):
    def __init__(self, status):
        super().__init__(status)
        self.status = status


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so a bad argument is one line and Blender keeps control."""

    def error(self, message):
        raise _UsageError(f"{self.prog}: error: {message} (see --help)")

    def exit(self, status=0, message=None):
        if message:
            sys.stderr.write(message)
        raise _ParserExit(status)


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


def build_parser(prog=f"blender -b FILE.blend -c {COMMAND}"):
    parser = _Parser(
        prog=prog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Full Body Adjust on the command line, without the user interface.\n\n"
            "  adjust    a frame range of one armature: hands and feet reach their target objects\n"
            "            (the armature's target slots), avoiding obstacles, solved in one batch\n"
            "  retarget  the motion of one armature carried onto another, adjusted so contacts hold\n\n"
            f"Run as `python -m {COMMAND} SUBCOMMAND FILE.blend [options]` with the bpy module, or as\n"
            f"`blender -b FILE.blend -c {COMMAND} SUBCOMMAND [options]` in Blender. "
            "`SUBCOMMAND --help` lists its options."),
        epilog=EXIT_CODES_HELP,
    )
    subparsers = parser.add_subparsers(dest="subcommand", metavar="SUBCOMMAND")

    adjust = subparsers.add_parser(
        "adjust", help="adjust a frame range of one armature so hands and feet reach their targets",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXIT_CODES_HELP,
        description=(
            "Adjust every frame of a range of one armature so its hands and feet reach the target objects set in\n"
            "its target slots (animated targets and moving obstacles are followed frame by frame), in one\n"
            "vectorised solve, and key the bones that moved: into the armature's action, or into a new action\n"
            "with --new-action so the original motion stays intact. The solver settings stored on the armature\n"
            "(its Full Body panel) are used unless overridden below."))
    _add_file_argument(adjust)
    adjust.add_argument("--armature", metavar="NAME",
                        help="the armature to adjust (default: the only armature with targets set; else the "
                             "active object, or the only armature)")
    _add_frame_arguments(adjust, "the armature's action (its manual frame range when set), or the scene's when "
                                 "it has no action")
    solver = adjust.add_argument_group("solver settings (default: those stored on the armature)")
    solver.add_argument("--variant", type=str.lower, choices=tuple(_VARIANTS),
                        help="how conflicting targets are settled: priority (the highest-priority reachable "
                             "target is always met), weighted (priority-weighted compromise) or fabrik (plain "
                             "FABRIK centroid, the baseline)")
    solver.add_argument("--margin", type=_non_negative, metavar="DISTANCE",
                        help="clearance kept from obstacle boxes, in scene units")
    solver.add_argument("--tolerance", type=_positive, metavar="DISTANCE",
                        help="a target counts as reached within this distance, in scene units")
    solver.add_argument("--max-iterations", type=_positive_int, metavar="N", help="iteration limit per solve")
    solver.add_argument("--no-limits", action="store_true",
                        help="ignore joint limits (elbows and knees may bend backwards)")
    _add_output_arguments(adjust, "write the keys into a new action of this name (a copy of the current one), so "
                                  "the original action stays intact (it gets a fake user)")
    adjust.set_defaults(work=_adjust)

    retarget = subparsers.add_parser(
        "retarget", help="carry the motion of one armature onto another and adjust it so contacts hold",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXIT_CODES_HELP,
        description=(
            "Carry the motion of a source armature onto a target armature of other proportions, then adjust the\n"
            "target so its contacts hold: feet on the ground, or a hand on an object it reaches (paper §6.2.3).\n"
            "Both armatures must be mappable onto the body model (their stored bone map or automatic mapping).\n"
            "In the preview the source is drawn in grey, the target in blue."))
    _add_file_argument(retarget)
    retarget.add_argument("--source", metavar="NAME", required=True, help="the armature whose motion is carried")
    retarget.add_argument("--target", metavar="NAME", required=True, help="the armature that receives it")
    _add_frame_arguments(retarget, "the source's action")
    retarget.add_argument("--contacts", nargs="+", action=_ContactsAction, metavar=("ground|object", "NAME"),
                          help="what must hold, given once or more (e.g. --contacts ground --contacts object Bar): "
                               "'ground' (planted feet rest on the floor and do not slide; the default) or 'object "
                               "NAME' (hands and feet touching object NAME in the source motion keep touching it); "
                               "feet still above the floor stand on something raised")
    retarget.add_argument("--exact", action="store_true",
                          help="the default, kept for older scripts: soles exactly on the ground, hands on objects "
                               "at the source's own world positions")
    _add_output_arguments(retarget, "name of the new action the target's motion is written into (default: "
                                    "'<source action>_<target>'); the target's previous action is kept")
    retarget.set_defaults(work=_retarget)
    return parser


def _add_file_argument(parser):
    parser.add_argument("file", nargs="?", metavar="FILE.blend",
                        help="the .blend file to open (under `blender -b FILE.blend -c ...` it may be left out: "
                             "the file Blender opened is used)")


def _add_frame_arguments(parser, default):
    parser.add_argument("--frame-start", type=int, metavar="N", help=f"first frame (default: the start of {default})")
    parser.add_argument("--frame-end", type=int, metavar="N", help=f"last frame (default: the end of {default})")


def _add_output_arguments(parser, new_action_help):
    parser.add_argument("--new-action", metavar="NAME", help=new_action_help)
    out = parser.add_argument_group("output (nothing is saved unless --output or --overwrite is given)")
    out.add_argument("--output", metavar="OUT.blend",
                     help="save the result as this new .blend file (the input file is left untouched)")
    out.add_argument("--overwrite", action="store_true",
                     help="save the result over the input .blend file (without --output), or allow --output to "
                          "name the input file")
    out.add_argument("--report", metavar="REPORT.json",
                     help="write a JSON report: frames, seconds, frames/s, reach error per effector (median, "
                          "p99, max; targets within and beyond reach apart), penetrations, and the frames "
                          "where a target was not met, with the reason")
    out.add_argument("--preview", metavar="PREVIEW.png",
                     help="draw a before/after picture: skeleton snapshots (front and side) at a few frames, "
                          "before in grey and after in blue with the targets, and the reach error over time")
    out.add_argument("--preview-frames", type=_positive_int, default=4, metavar="N",
                     help="number of snapshot frames in the preview (default: 4)")
    out.add_argument("--quiet", action="store_true", help="no progress line on stderr")
    out.add_argument("--debug", action="store_true", help="print the Python traceback of an internal error")


class _ContactsAction(argparse.Action):
    """--contacts ground | --contacts object NAME, given once or more: a list of ('ground', None) and
    ('object', NAME), in order, each once."""

    def __call__(self, parser, namespace, values, option_string=None):
        kind, names = values[0].lower(), values[1:]
        if kind == "ground" and not names:
            contact = ("ground", None)
        elif kind == "object" and len(names) == 1:
            contact = ("object", names[0])
        elif kind == "object":
            raise argparse.ArgumentError(self, "'object' takes exactly one object NAME")
        elif kind == "ground":
            raise argparse.ArgumentError(self, "'ground' takes no name")
        else:
            raise argparse.ArgumentError(self, f"expected 'ground' or 'object NAME', got '{values[0]}'")
        given = list(getattr(namespace, self.dest, None) or [])
        setattr(namespace, self.dest, given + [contact] if contact not in given else given)


def _positive(text):
    value = _float(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def _non_negative(text):
    value = _float(text)
    if not value >= 0.0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def _float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text}") from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    return value


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return value


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
    input_path = _input_path(args)
    saved = _checked_outputs(args, input_path)
    if not _same_file(input_path, batch.current_file()):
        batch.open_blend(input_path)
    result = args.work(args, bpy.context)

    report = summary.summarize_outcome(
        result.outcome, result.seconds, command=args.subcommand, file=os.path.abspath(input_path),
        output=os.path.abspath(saved) if saved else None, blender=bpy.app.version_string, **result.details)
    if saved is not None:
        batch.save_blend(saved)
    if args.report:
        _write_text(args.report, summary.to_json(report))
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


def _input_path(args):
    if args.file is not None:
        if not os.path.exists(args.file):
            raise CommandError(f"no such file: {args.file}")
        return args.file
    if batch.current_file():
        return batch.current_file()
    raise CommandError("no .blend file: give FILE.blend")


def _checked_outputs(args, input_path):
    """Check every output path before anything runs; returns the .blend path to save to (None: none)."""
    if args.output is not None:
        blend = args.output
        if _same_file(blend, input_path) and not args.overwrite:
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
        if option != "--overwrite" and option != "--output" and _same_file(path, input_path):
            raise CommandError(f"{option} {path} would overwrite the input file")
        _check_writable(path, option)
        key = os.path.realpath(path)
        if key in seen:
            raise CommandError(f"{option} and {seen[key]} name the same file: {path}")
        seen[key] = option
    return blend


def _check_writable(path, option):
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise CommandError(f"{option} {path} is a folder")
    if not os.path.isdir(folder):
        raise CommandError(f"{option} {path}: folder {folder} does not exist")
    if os.path.exists(path) and not os.access(path, os.W_OK):
        raise CommandError(f"{option} {path}: file is not writable")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise CommandError(f"{option} {path}: folder {folder} is not writable")


def _same_file(a, b):
    if not a or not b:
        return False
    if os.path.exists(a) and os.path.exists(b):
        return os.path.samefile(a, b)
    return os.path.realpath(a) == os.path.realpath(b)


def _write_text(path, text):
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
    adjustment.check_armature(obj)
    batch.check_mappable(obj, "--armature")
    start, end = batch.frame_range(obj, context.scene, args.frame_start, args.frame_end)
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

def _retarget(args, context):
    source = batch.armature_named(context, args.source, "--source")
    target = batch.armature_named(context, args.target, "--target")
    if source == target:
        raise CommandError("--source and --target are the same armature")
    adjustment.check_armature(target)
    batch.check_mappable(source, "--source")
    batch.check_mappable(target, "--target")
    contacts = [kind if name is None else (kind, batch.object_named(context, name, "--contacts object"))
                for kind, name in args.contacts or [("ground", None)]]
    start, end = batch.frame_range(source, context.scene, args.frame_start, args.frame_end)

    frames = np.arange(start, end + 1, dtype=np.float64)
    shown = frames[preview.pick_snapshots(len(frames), args.preview_frames)]
    progress = _progress(args, len(frames), f"retarget '{source.name}' -> '{target.name}'")
    started = time.perf_counter()
    outcome = retarget_motion(context, source, target, start, end, contacts=contacts, new_action=args.new_action,
                              progress=progress)
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
               "contacts": outcome.contact_report,
               "action": action.name if action is not None else batch.action_name(target)}
    return WorkResult(outcome=outcome, seconds=seconds, figure=figure, details=details)


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
