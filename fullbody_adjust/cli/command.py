# SPDX-License-Identifier: GPL-3.0-or-later
"""Running one command line: parse it, run its subcommand (``adjust``, ``retarget``, or a batch of clip files in
``clips``), write the .blend, the report and the picture, print one line, and return the exit code. Every
expected problem — bad arguments, a missing file, an unknown armature, a frame range outside the action, a rig
that cannot be mapped, an unwritable output — ends the run with one line on stderr, a non-zero exit code and no
file written; the input .blend is only ever written with --overwrite.
"""

import os
import sys
import traceback

import bpy

from ..bridge import files as batch
from ..bridge.errors import AdjustError
from ..reporting import preview, summary
from . import clips
from .adjust import adjust
from .files import CommandError, checked_outputs, input_path, one_line, same_file, write_png, write_text
from .parser import (COMMAND, EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_OK, EXIT_TARGETS_MISSED, ParserExit, UsageError,
    build_parser, file_only_options)
from .retarget import retarget

_WORK = {"adjust": adjust, "retarget": retarget}


def run(argv, prog):
    """Run the command line ``argv`` (the arguments after the command id); returns the exit code."""
    parser = build_parser(prog)
    try:
        args = parser.parse_args(list(argv))
    except ParserExit as ex:
        return ex.status
    except UsageError as ex:
        print(str(ex), file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.subcommand is None:
        print(f"{prog}: error: choose a subcommand: adjust or retarget (see --help)", file=sys.stderr)
        return EXIT_BAD_INPUT
    where = f"{COMMAND} {args.subcommand}"
    ignored = file_only_options(args)
    if ignored:
        print(f"{where}: error: {', '.join(ignored)} act on clips from files (--source-file), not on --source "
              f"(see --help)", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        if getattr(args, "source_file", None):
            return clips.run(args)  # the batch of clip files: worker processes, one row per clip
        return _execute(args)
    except (CommandError, AdjustError) as ex:
        print(f"{where}: error: {one_line(ex)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as ex:  # a bug: still one line (and the traceback on request), never a Blender crash
        if args.debug:
            traceback.print_exc()
        print(f"{where}: internal error: {type(ex).__name__}: {one_line(ex)} (a bug; --debug shows where)",
              file=sys.stderr)
        return EXIT_INTERNAL


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
        write_png(args.preview, preview.render(result.figure))

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
