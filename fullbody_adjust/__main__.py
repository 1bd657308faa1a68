# SPDX-License-Identifier: GPL-3.0-or-later
"""``python -m fullbody_adjust SUBCOMMAND FILE.blend [options]`` with the bpy module: registers the extension's
classes in this Python, then runs the same command as ``blender -b FILE.blend -c fullbody_adjust SUBCOMMAND
[options]`` (cli.main). ``--help`` lists the subcommands and exit codes."""

import sys

from .bpy_exit import leave


def run(argv):
    import bpy  # noqa: F401  (the bpy module must be importable: this is for the bpy wheel)

    from . import cli, register
    from .cli.clips import WORKER_FLAG

    register()
    if argv[:1] == [WORKER_FLAG]:  # a worker of a clip batch, started by cli.clips
        from .cli import worker as clip_worker
        clip_worker.serve()
        return 0
    return cli.main(argv, prog="python -m fullbody_adjust")


def worker():
    """A worker of a clip batch under `blender -b --python-expr` (cli.clips.worker_command)."""
    from . import register
    from .cli import worker as clip_worker

    register()
    clip_worker.serve()
    leave(0)


if __name__ == "__main__":
    try:
        code = run(sys.argv[1:])
    except ModuleNotFoundError as ex:
        if ex.name != "bpy":
            raise
        print("python -m fullbody_adjust: error: the bpy module is not installed in this Python "
              "(pip install bpy, or run `blender -b FILE.blend -c fullbody_adjust ...`)", file=sys.stderr)
        code = 3
    leave(code)
