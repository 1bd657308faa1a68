# SPDX-License-Identifier: GPL-3.0-or-later
"""The command line's arguments: the parser of ``adjust`` and ``retarget``, their options, help and exit codes.
Parsing only: running a subcommand is ``command``'s; a bad argument raises instead of exiting, so Blender keeps
control and the run ends with one line."""

import argparse
import sys

import numpy as np

from ..solver.retarget.partial import BODY_GROUPS, parse_groups
from ..solver.retarget.root_motion import DEFAULT_SMOOTHING
from ..solver.vocabulary import VARIANTS

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

AXES = ("X", "Y", "Z", "-X", "-Y", "-Z")

VARIANT_ENUMS = {variant: variant.upper() for variant in VARIANTS}


# The retarget options that act on clips from files only: option -> (its attribute, its default).
FILE_ONLY = {"--clip-scale": ("clip_scale", None), "--clip-forward": ("clip_forward", None),
             "--clip-up": ("clip_up", None), "--clip-fps": ("clip_fps", "scene"), "--take": ("take", None),
             "--clip-start-frame": ("clip_start_frame", 1), "--jobs": ("jobs", None),
             "--clip-timeout": ("clip_timeout", None), "--output-dir": ("output_dir", None),
             "--skip-existing": ("skip_existing", False), "--keep-sources": ("keep_sources", False),
             "--format": ("format", "blend"), "--armature-only": ("armature_only", False),
             "--scheduler": ("scheduler", None)}


def file_only_options(args):
    """The options of FILE_ONLY given to a retarget of an armature in the file (--source): they would do nothing."""
    if getattr(args, "subcommand", None) != "retarget" or args.source_file:
        return []
    return [option for option, (name, default) in FILE_ONLY.items() if getattr(args, name) != default]


class UsageError(Exception):
    pass


class ParserExit(Exception):
    def __init__(self, status):
        super().__init__(status)
        self.status = status


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so a bad argument is one line and Blender keeps control."""

    def error(self, message):
        raise UsageError(f"{self.prog}: error: {message} (see --help)")

    def exit(self, status=0, message=None):
        if message:
            sys.stderr.write(message)
        raise ParserExit(status)



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

    adjust = _add_subcommand(
        subparsers, "adjust", "adjust a frame range of one armature so hands and feet reach their targets",
        "Adjust every frame of a range of one armature so its hands and feet reach the target objects set in\n"
        "its target slots (animated targets and moving obstacles are followed frame by frame), in one\n"
        "vectorised solve, and key the bones that moved: into the armature's action, or into a new action\n"
        "with --new-action so the original motion stays intact. The solver settings stored on the armature\n"
        "(its Full Body panel) are used unless overridden below.")
    _add_file_argument(adjust)
    adjust.add_argument("--armature", metavar="NAME",
                        help="the armature to adjust (default: the only armature with targets set; else the "
                             "active object, or the only armature)")
    _add_frame_arguments(adjust, "the armature's action (its manual frame range when set), or the scene's when "
                                 "it has no action")
    solver = adjust.add_argument_group("solver settings (default: those stored on the armature)")
    solver.add_argument("--variant", type=str.lower, choices=tuple(VARIANT_ENUMS),
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
    adjust.set_defaults(work="adjust")

    retarget = _add_subcommand(
        subparsers, "retarget", "carry the motion of one armature onto another and adjust it so contacts hold",
        "Carry the motion of a source armature onto a target armature of other proportions, then adjust the\n"
        "target so its contacts hold: feet on the ground, or a hand on an object it reaches (paper §6.2.3).\n"
        "Both armatures must be mappable onto the body model (their stored bone map or automatic mapping).\n"
        "In the preview the source is drawn in grey, the target in blue.")
    _add_file_argument(retarget)
    source = retarget.add_mutually_exclusive_group(required=True)
    source.add_argument("--source", metavar="NAME", help="the armature of FILE.blend whose motion is carried")
    source.add_argument("--source-file", metavar="CLIP", action="append",
                        help="a motion clip to carry instead: a .bvh, .fbx, .glb or .gltf file, a folder of them or a glob "
                             "(repeatable). Each clip is imported in a worker process and becomes one new action "
                             "on the target named after the clip (or one .blend per clip with --output-dir)")
    retarget.add_argument("--target", metavar="NAME", required=True, help="the armature that receives it")
    _add_frame_arguments(retarget, "the source's action, within the scene's frame range when they overlap (a "
                                   "clip from a file: its whole action)")
    retarget.add_argument("--floor", type=_float, metavar="Z",
                          help="world height of the floor the feet stand on: the source's ground is moved there "
                               "(default: 0 for clips from files with ground contacts; else the source's own "
                               "ground)")
    clips = retarget.add_argument_group("clips from files (with --source-file)")
    clips.add_argument("--clip-scale", type=_positive, metavar="S",
                       help="metres per clip unit (default: 0.056444 for BVH, the CMU database's unit; 1 for FBX and glTF, "
                            "whose importer reads the file's own units, as Mixamo's)")
    clips.add_argument("--clip-forward", type=str.upper, choices=AXES, metavar="AXIS",
                       help="the clip's forward axis, one of X Y Z -X -Y -Z (default: -Z for BVH; the file's own "
                            "for FBX)")
    clips.add_argument("--clip-up", type=str.upper, choices=AXES, metavar="AXIS",
                       help="the clip's up axis (default: Y for BVH; the file's own for FBX)")
    clips.add_argument("--clip-fps", choices=("scene", "clip"), default="scene",
                       help="'scene' (default): the clip's time is resampled to the target file's frame rate, "
                            "so the motion keeps its speed; 'clip' (BVH only): one key per clip frame and the "
                            "scene takes the clip's frame rate (one .blend per clip)")
    clips.add_argument("--take", metavar="NAME",
                       help="the take to carry from FBX and glTF files that hold several, by the name the file "
                            "gives it (e.g. Running_A; default: the longest take); the action (or file) is named "
                            "<clip>_<take>")
    clips.add_argument("--clip-start-frame", type=int, default=1, metavar="N",
                       help="the scene frame the clip's first frame lands on (default: 1)")
    clips.add_argument("--jobs", type=_positive_int, metavar="N",
                       help="clips retargeted at once, each in its own worker process (default: the number of "
                            "cores)")
    clips.add_argument("--clip-timeout", type=_positive, metavar="SECONDS",
                       help="a clip still running after this many seconds is stopped and reported failed, and the "
                            "batch goes on (default: no limit)")
    clips.add_argument("--output-dir", metavar="DIR",
                       help="write one file per clip, DIR/<clip>.blend (the target file with that clip's "
                            "action; see --format), instead of all actions into --output")
    clips.add_argument("--skip-existing", action="store_true",
                       help="resume a batch: leave out clips already done (their DIR/<clip>.blend exists, or the "
                            "input file already has the clip's action)")
    clips.add_argument("--keep-sources", action="store_true",
                       help="keep the imported source armatures in the output (default: removed)")
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
    _add_mirror_arguments(retarget)
    _add_root_motion_arguments(retarget)
    _add_engine_arguments(retarget)
    _add_cluster_arguments(retarget)
    retarget.set_defaults(work="retarget")
    return parser


def _add_mirror_arguments(retarget):
    """--mirror and --groups: the source's motion mirrored, only some body groups carried."""
    group = retarget.add_argument_group("mirrored and partial retargets")
    group.add_argument("--mirror", action="store_true",
                       help="carry the source's motion mirrored: left and right swapped through the bone map and "
                            "reflected across the character's own sagittal plane (its left-foot plants become "
                            "right-foot plants; contact objects are held where their mirror images stand)")
    group.add_argument("--groups", type=_body_groups, metavar="GROUP,...",
                       help=f"carry only these body groups, comma separated, of {', '.join(BODY_GROUPS)} (the trunk "
                            f"with the pelvis and head, each arm with its hand and fingers, each leg with its "
                            f"foot); every other bone keeps the target's own F-Curves, key for key")


def _body_groups(text):
    try:
        return parse_groups(text)
    except ValueError as ex:
        raise argparse.ArgumentTypeError(str(ex)) from None


def _add_root_motion_arguments(retarget):
    motion = retarget.add_argument_group("root motion (for game engines)")
    motion.add_argument("--root-motion", choices=("hips", "bone", "object", "in-place"), default="hips",
                        help="where the body's travel goes: 'hips' (default: on the hips, as captured); 'bone' (its "
                             "horizontal travel and turn about the vertical on the root bone above the hips, the "
                             "hips keeping their height and sway; see --root-bone); 'object' (on the armature "
                             "object's location and rotation keys); 'in-place' (removed: the body stays over its "
                             "rest place, facing its rest heading). Planted feet hold in the world the root and "
                             "the pose build")
    motion.add_argument("--root-bone", metavar="NAME",
                        help="with --root-motion bone: the root bone, an existing bone above the hips, or a new one "
                             "created at the floor under the hips as parent of the hips' hierarchy (default: the "
                             "topmost bone above the hips; a rig with none needs this)")
    motion.add_argument("--root-smoothing", type=_seconds, metavar="SECONDS",
                        help="with --root-motion bone, object or in-place: the root follows the hips' ground path "
                             "and heading smoothed over this many seconds, steady, the hips keeping their sway and "
                             f"each step's back-and-forth relative to it (default {DEFAULT_SMOOTHING:g}, a walking "
                             f"stride; 0: the root follows the hips exactly)")


def _seconds(text):
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 <= value <= 1e6:
        raise argparse.ArgumentTypeError(f"{text!r} is not 0 or more seconds")
    return value


def _add_engine_arguments(retarget):
    engine = retarget.add_argument_group("engine-ready files (with --source-file and --output-dir)")
    engine.add_argument("--format", choices=("blend", "fbx", "glb"), default="blend",
                        help="the file written per clip in --output-dir: 'blend' (default: the target file with "
                             "the clip's action), 'fbx' or 'glb' (glTF binary): the target armature with the "
                             "meshes it deforms and the clip baked one key per frame, through Blender's own "
                             "exporter, set as game engines import it (deforming bones only, no leaf bones; FBX "
                             "Y up, -Z forward, the scene's unit in the file's unit scale; glTF Y up, metres)")
    engine.add_argument("--armature-only", action="store_true",
                        help="with --format fbx or glb: the armature and its motion alone, without its meshes (an "
                             "animation for a skeleton the engine already has)")


def _add_cluster_arguments(retarget):
    cluster = retarget.add_argument_group("a Dask cluster (with --source-file)")
    cluster.add_argument("--scheduler", metavar="ADDRESS",
                         help="send the clips to the Dask scheduler at ADDRESS (e.g. tcp://10.0.0.5:8786) instead of "
                              "local worker processes: each Dask worker runs them as --jobs does (it needs the "
                              "'distributed' package, as this Python does); the input, the clips and the outputs "
                              "must be on storage every worker sees under the same paths")


def _add_subcommand(subparsers, name, summary, description):
    """A subcommand's parser: ``summary`` in the command's list, ``description`` (laid out as written) and the
    exit codes in its own --help."""
    return subparsers.add_parser(name, help=summary, description=description, epilog=EXIT_CODES_HELP,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)


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
                     help="write a JSON report (with --source-file: one row per clip, and a CSV of the rows "
                          "beside it, REPORT.csv): frames, seconds, frames/s, reach error per effector (median, "
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


def _argument_type(convert, accept, rule, kind="number"):
    """An argparse type: ``convert(text)``, refused in one line when the text is not a ``kind`` or when
    ``accept(value)`` is false (the value 'must be ``rule``')."""
    def parse(text):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a {kind}: {text}") from None
        if not accept(value):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text}")
        return value
    return parse


_float = _argument_type(float, np.isfinite, "finite")
_positive = _argument_type(_float, lambda value: value > 0.0, "> 0")
_non_negative = _argument_type(_float, lambda value: value >= 0.0, ">= 0")
_positive_int = _argument_type(int, lambda value: value >= 1, ">= 1", kind="whole number")
