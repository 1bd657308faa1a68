# SPDX-License-Identifier: GPL-3.0-or-later
"""The command line: ``blender -b FILE.blend -c fullbody_adjust SUBCOMMAND ...`` (registered here with
``bpy.utils.register_cli_command``) and, with the bpy wheel, ``python -m fullbody_adjust SUBCOMMAND FILE.blend
...`` (``__main__.py``). Both end in ``main(argv)``, which returns the exit code.

Thin, and imported one way: ``command`` runs a command line, with the arguments of ``parser``, the work of
``adjust`` and ``retarget`` (one armature's motion onto another) or ``clips`` (a batch of clip files, run by the
worker processes of ``pool``, each running ``worker``), and the files and error line of ``files``. The work
itself is the bridge's (``bridge.adjustment``, ``bridge.retarget``, the file chores in ``bridge.batch``), the
report, progress line and picture ``reporting``'s. This file imports no bpy until the command runs or registers,
so ``parser`` and ``pool`` work in a Python without bpy.
"""

from .parser import COMMAND, build_parser

__all__ = ("COMMAND", "build_parser", "main", "register", "unregister")

PROG = f"blender -b FILE.blend -c {COMMAND}"


def main(argv, prog=PROG):
    """Run the command line ``argv`` (the arguments after the command id); returns the exit code."""
    from .command import run

    return run(argv, prog)


# --- registration ----------------------------------------------------------------------------------------------

_handle = None


def register():
    global _handle
    import bpy

    _handle = bpy.utils.register_cli_command(COMMAND, main)


def unregister():
    global _handle
    if _handle is not None:
        import bpy

        bpy.utils.unregister_cli_command(_handle)
        _handle = None
