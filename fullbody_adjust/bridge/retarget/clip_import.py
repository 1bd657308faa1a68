"""Importing a motion clip file (BVH, FBX or glTF) through Blender's own importers as a source armature, and
removing everything the import made once the clip is carried over. Every problem is an AdjustError with one line.

An FBX or glTF file may hold several takes (actions): the one named by ImportOptions.take is carried, else the
longest (a one-frame 'Targeting Pose' or 'T-Pose' beside the motion is a pose, not the clip)."""

from dataclasses import dataclass
import os

import addon_utils
import bpy
from mathutils import Matrix
import numpy as np

from ..errors import AdjustError
from ..writing import keyframes

CMU_SCALE = 0.056444  # metres per unit of the CMU database's BVH files (the most common free mocap)
FORMATS = {".bvh": "io_anim_bvh", ".fbx": "io_scene_fbx", ".glb": "io_scene_gltf2", ".gltf": "io_scene_gltf2"}
FORMAT_NAMES = ".bvh, .fbx, .glb or .gltf"


@dataclass(frozen=True)
class ImportOptions:
    """How a clip is read. None: the format's default (BVH: CMU's unit, -Z forward, Y up; FBX: the file's own
    units and axes, as Mixamo's files need; glTF: metres, Y up as the format fixes, its axes not settable).
    fps 'scene' resamples the clip's time to the scene's frame rate; 'clip' keys one frame per clip frame and
    gives the scene the clip's rate (BVH only). take: the name of the take to carry (FBX, glTF; None: the
    longest)."""

    scale: float = None
    forward: str = None
    up: str = None
    fps: str = "scene"
    start_frame: int = 1
    take: str = None


def clip_format(path):
    """'.bvh', '.fbx', '.glb' or '.gltf' (lower case); AdjustError for anything else."""
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in FORMATS:
        raise AdjustError(f"{path}: not a clip file (use {FORMAT_NAMES})")
    return suffix


def import_clip(context, path, options=ImportOptions()):
    """Import the clip at ``path``; returns (its armature object, the ids the import added). The importer's
    own error, or a file with no armature or several, is an AdjustError and leaves nothing behind."""
    suffix = clip_format(path)
    if not os.path.isfile(path):
        raise AdjustError(f"No such clip file: {path}")
    if suffix == ".bvh" and options.take is not None:
        raise AdjustError(f"{os.path.basename(path)}: a BVH file holds one take (--take is for FBX and glTF)")
    _enable(FORMATS[suffix])
    before = _ids()
    try:
        if suffix == ".bvh":
            _import_bvh(path, options)
        elif suffix == ".fbx":
            _import_fbx(path, options)
        else:
            _import_gltf(path, options)
    except Exception as ex:  # the importers raise anything on a corrupt file: report it, keep the batch going
        remove_ids(_ids() - before)
        raise AdjustError(f"Cannot import {os.path.basename(path)}: {_importer_message(ex)}") from None
    added = _ids() - before
    armatures = [i for i in added if isinstance(i, bpy.types.Object) and i.type == 'ARMATURE']
    if len(armatures) != 1:
        remove_ids(added)
        raise AdjustError(f"{os.path.basename(path)} holds {len(armatures) or 'no'} armatures: expected one")
    source = armatures[0]
    if source.animation_data is None or source.animation_data.action is None:
        remove_ids(added)
        raise AdjustError(f"{os.path.basename(path)} has no motion")
    try:
        _carry_take(source, [i for i in added if isinstance(i, bpy.types.Action)], options.take, path)
        if suffix in (".glb", ".gltf"):
            _place_gltf(source, added, options)
    except AdjustError:
        remove_ids(added)
        raise
    for action in (i for i in added if isinstance(i, bpy.types.Action)):
        action.name = f"{action.name} (source)"  # the clip's own name is for the action the retarget makes
    context.view_layer.update()
    return source, added


def _carry_take(source, actions, take, path):
    """Make the take named ``take`` the armature's action, else the longest of the clip's takes. An FBX or glTF
    file may hold several (Kenney's and Mixamo's FBX add a one-frame 'Targeting Pose' beside the motion, KayKit's
    glTF a library of moves) and Blender's importers leave the first one active, which may carry a still pose
    instead of the clip. A take of one frame is a pose, not a clip; between takes of the same length the
    importer's choice stands. A take is named as the file names it: the importers prefix the object's name
    ('Root|Root|Run', 'Rig_Medium|Running_A') and Blender 4.2's glTF importer suffixes it ('..._Rig_Medium')."""
    anim = source.animation_data
    current = anim.action

    def length(action):
        start, end = action.frame_range
        return end - start

    if take is not None:
        named = [a for a in actions if take in (a.name, _take_name(a.name, source.name))]
        if not named:
            found = ", ".join(sorted(_take_name(a.name, source.name) for a in actions)) or "none"
            raise AdjustError(f"{os.path.basename(path)} has no take '{take}' (its takes: {found})")
        chosen = named[0]
    else:
        chosen = max(actions, key=length, default=current)
        if length(chosen) <= length(current):
            chosen = current
    if chosen is not current:
        anim.action = chosen
        # Blender 4.4+ keeps a slot only where the new action has one named as the old one was: 5.0's FBX importer
        # names every take's slot alike, 4.5's after its take, so the new take was left with no slot (unanimated)
        if bpy.app.version >= (4, 4, 0) and anim.action_slot is None and len(anim.action_suitable_slots):
            anim.action_slot = anim.action_suitable_slots[0]


def _take_name(action_name, object_name):
    """A take's own name from its action's: the part after the importer's last '|', without the '_<object>'
    Blender 4.2's glTF importer appends."""
    name = action_name.rsplit("|", 1)[-1]
    suffix = f"_{object_name}"
    return name[:-len(suffix)] if name.endswith(suffix) and len(name) > len(suffix) else name


def remove_ids(ids):
    """Remove what an import added (objects, their armatures and meshes, actions...), leaving no orphans."""
    alive = [i for i in ids if _is_alive(i)]
    if alive:
        bpy.data.batch_remove(alive)


def _import_bvh(path, options):
    scene = bpy.context.scene
    resample = options.fps == "scene" and not _same_rate(bvh_frame_rate(path), scene.render.fps / scene.render.fps_base)
    bpy.ops.import_anim.bvh(
        filepath=os.path.abspath(path), global_scale=options.scale or CMU_SCALE,
        axis_forward=options.forward or '-Z', axis_up=options.up or 'Y', frame_start=options.start_frame,
        use_fps_scale=resample, update_scene_fps=options.fps == "clip", update_scene_duration=False)


def bvh_frame_rate(path):
    """Frames per second a BVH file's 'Frame Time:' line gives (None when it has none)."""
    with open(path, "r", encoding="utf-8", errors="replace") as lines:
        for line in lines:
            if line.strip().lower().startswith("frame time:"):
                try:
                    seconds = float(line.split(":", 1)[1])
                except ValueError:
                    return None
                return 1.0 / seconds if seconds > 0.0 else None
    return None


def _same_rate(clip_fps, scene_fps):
    """True when the clip's rate is the scene's but for the rounding of its frame time (CMU's '.0083333' is
    120.0005 fps): its keys then go one on each frame, not a hair off them."""
    return clip_fps is not None and abs(clip_fps - scene_fps) <= 1e-4 * scene_fps


def _import_fbx(path, options):
    if options.fps == "clip":
        raise AdjustError(f"{os.path.basename(path)}: --clip-fps clip is for BVH files (FBX keys land on the "
                          f"scene's frame rate)")
    manual = options.forward is not None or options.up is not None
    bpy.ops.import_scene.fbx(
        filepath=os.path.abspath(path), global_scale=options.scale or 1.0, use_anim=True,
        anim_offset=float(options.start_frame), use_manual_orientation=manual,
        axis_forward=options.forward or '-Z', axis_up=options.up or 'Y')


def _import_gltf(path, options):
    name = os.path.basename(path)
    if options.fps == "clip":
        raise AdjustError(f"{name}: --clip-fps clip is for BVH files (glTF keys land on the scene's frame rate)")
    if options.forward is not None or options.up is not None:
        raise AdjustError(f"{name}: a glTF file's axes are fixed by the format (Y up, metres): --clip-forward and "
                          f"--clip-up are for BVH and FBX files")
    bpy.ops.import_scene.gltf(filepath=os.path.abspath(path))


def _place_gltf(source, added, options):
    """A glTF clip as the FBX importer would leave it: scaled by ``options.scale`` about the origin, and its
    take's first key on ``options.start_frame`` (Blender's glTF importer keys a take from about frame 0)."""
    if options.scale is not None and options.scale != 1.0:
        top = source
        while top.parent is not None and top.parent in added:
            top = top.parent
        top.matrix_world = Matrix.Scale(options.scale, 4) @ top.matrix_world
    shift = float(options.start_frame) - float(source.animation_data.action.frame_range[0])
    if shift:
        for fcurve in keyframes.animating_fcurves(source):
            for prop in ("co", "handle_left", "handle_right"):
                values = np.empty(2 * len(fcurve.keyframe_points))
                fcurve.keyframe_points.foreach_get(prop, values)
                values[0::2] += shift
                fcurve.keyframe_points.foreach_set(prop, values)
            fcurve.update()


def _enable(module):
    if not addon_utils.check(module)[1]:
        addon_utils.enable(module, default_set=False)


def _ids():
    """Every id that an import can add."""
    out = set()
    for collection in (bpy.data.objects, bpy.data.armatures, bpy.data.actions, bpy.data.meshes,
                       bpy.data.materials, bpy.data.images, bpy.data.collections):
        out.update(collection)
    return out


def _is_alive(datablock):
    try:
        datablock.name
    except ReferenceError:
        return False
    return True


def _importer_message(ex):
    text = " ".join(str(ex).split())
    for prefix in ("Error: Python: ", "Error: "):
        if text.startswith(prefix):
            text = text[len(prefix):]
    if "Traceback" in text:  # an operator's Python error: its last line (before Location:) says what happened
        lines = [line.strip() for line in str(ex).strip().splitlines()
                 if line.strip() and not line.strip().startswith("Location:")]
        text = lines[-1] if lines else text
    return text[:300] or type(ex).__name__
