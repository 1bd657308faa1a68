# SPDX-License-Identifier: GPL-3.0-or-later
"""Leaving a Python process that used the bpy module: without the module's own teardown, which is unreliable once
Python shuts down (Blender 4.2 crashes on a registered property's Python callback: SIGSEGV, exit 139; 4.5 can hang
on its file-closing thread; see tests/conftest.py). For ``python -m fullbody_adjust``, its clip workers and the
benches."""

import os
import shutil
import sys


def leave(code):
    """Exit with ``code`` now, stdout and stderr flushed, removing the temporary folder Blender would have removed."""
    sys.stdout.flush()
    sys.stderr.flush()
    bpy = sys.modules.get("bpy")
    if bpy is not None:
        shutil.rmtree(bpy.app.tempdir, ignore_errors=True)
    os._exit(code)
