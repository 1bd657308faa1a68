"""Set-up shared by every test: the repository root on sys.path, a throwaway Blender user folder, and an exit
that skips Blender's unreliable teardown.

`import fullbody_adjust.solver` then works with or without bpy (the package's __init__ imports no bpy).
"""

import atexit
import os
import shutil
import sys
import tempfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

_blender_user_dir = None


def pytest_configure(config):
    # bpy reads BLENDER_USER_RESOURCES when it is first imported (before any test module imports it): a throwaway
    # folder keeps the tests from reading or writing the developer's own Blender preferences and extensions.
    global _blender_user_dir
    if "BLENDER_USER_RESOURCES" not in os.environ:
        _blender_user_dir = tempfile.mkdtemp(prefix="fullbody_adjust-blender-user-")
        os.environ["BLENDER_USER_RESOURCES"] = _blender_user_dir


def pytest_unconfigure(config):
    if _blender_user_dir is not None:
        shutil.rmtree(_blender_user_dir, ignore_errors=True)


def pytest_sessionfinish(session, exitstatus):
    # The bpy module's own C++ teardown after Python has shut down is unreliable: Blender 4.2 crashes (a static
    # destructor frees registered UI classes through the finalized interpreter: SIGSEGV, exit 139) and 4.5 can
    # hang for ever (a static destructor waits on its file-closing thread), both after every test has passed.
    # So once bpy was used, leave at the first exit handler with pytest's own exit code, removing the
    # temporary folder Blender would have removed.
    bpy = sys.modules.get("bpy")
    if bpy is not None:
        atexit.register(_exit_before_blender_teardown, session, bpy.app.tempdir)


def _exit_before_blender_teardown(session, blender_tempdir):
    sys.stdout.flush()
    sys.stderr.flush()
    shutil.rmtree(blender_tempdir, ignore_errors=True)
    os._exit(int(session.exitstatus))
