"""What the benches' command lines share: whole-number options, and stdout kept for the one JSON report."""

import argparse
import contextlib
import ctypes
import json
import os
import sys


def whole_number_options(doc, *options):
    """The bench's parsed arguments: each option (flag, default, help) takes a whole number; the description is
    the first line of the bench's docstring ``doc``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    for flag, default, text in options:
        parser.add_argument(flag, type=int, default=default, help=text)
    return parser.parse_args()


@contextlib.contextmanager
def stdout_to_stderr():
    """Send everything written to file descriptor 1 (Python's and C's stdout: the BVH importer, rigify,
    Blender itself) to stderr, so stdout carries only the JSON."""
    def flush_all():
        sys.stdout.flush()
        if libc is not None:
            libc.fflush(None)  # C stdio buffers hold text meant for the descriptor they were written to

    try:
        libc = ctypes.CDLL(None)
    except (OSError, TypeError):  # no C library to open by no name (Windows): Python's buffer is still flushed
        libc = None
    flush_all()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        yield
    finally:
        flush_all()
        os.dup2(saved, 1)
        os.close(saved)


def print_report(measure, args, indent=2):
    """Run ``measure(args)`` with everything else it writes sent to stderr, then print its report (a dict) as
    the one JSON object on stdout."""
    with stdout_to_stderr():
        report = measure(args)
    print(json.dumps(report, indent=indent))

