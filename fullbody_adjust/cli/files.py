# SPDX-License-Identifier: GPL-3.0-or-later
"""What the subcommands share: the input file and the outputs checked before anything runs, writing the report
and the picture, the progress line, and the one-line error (CommandError) every expected problem ends in."""

from dataclasses import dataclass
import os

from ..bridge import files as batch
from ..reporting import png
from ..reporting.progress import ConsoleProgress, NoProgress


class CommandError(Exception):
    """A problem with the arguments or the input: exit 2 with this one line."""


@dataclass
class WorkResult:
    """What a subcommand's work hands back: an Outcome-like result (see reporting.summary), the solve's
    seconds, the preview's data (None without --preview) and items for the report's header."""

    outcome: object
    seconds: float
    figure: object
    details: dict


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


def write_png(path, image):
    try:
        png.write_png(path, image)
    except OSError as ex:
        raise CommandError(f"cannot write {path}: {ex.strerror}") from None


def progress_line(args, frames, label):
    return NoProgress() if args.quiet else ConsoleProgress(frames, label)


def one_line(ex):
    return " ".join(str(ex).split())
