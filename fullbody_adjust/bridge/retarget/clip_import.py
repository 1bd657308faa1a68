"""Importing a motion clip file (BVH or FBX) through Blender's own importers as a source armature, and removing
everything the import made once the clip is carried over. Every problem is an AdjustError with one line."""

from dataclasses import dataclass
import os

import addon_utils
import bpy

from ..errors import AdjustError

CMU_SCALE = 0.056444  # metres per unit of the CMU database's BVH files (the most common free mocap)
FORMATS = {".bvh": "io_anim_bvh", ".fbx": "io_scene_fbx"}


@dataclass(frozen=True)
class ImportOptions:
    """How a clip is read. None: the format's default (BVH: CMU's unit, -Z forward, Y up; FBX: the file's own
    units and axes, as Mixamo's files need). fps 'scene' resamples the clip's time to the scene's frame rate;
    'clip' keys one frame per clip frame and gives the scene the clip's rate (BVH only)."""

    scale: float = None
    forward: str = None
    up: str = None
    fps: str = "scene"
    start_frame: int = 1


def clip_format(path):
    """'.bvh' or '.fbx' (lower case); AdjustError for anything else."""
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in FORMATS:
        raise AdjustError(f"{path}: not a clip file (use .bvh or .fbx)")
    return suffix


def import_clip(context, path, options=ImportOptions()):
    """Import the clip at ``path``; returns (its armature object, the ids the import added). The importer's
    own error, or a file with no armature or several, is an AdjustError and leaves nothing behind."""
    suffix = clip_format(path)
    if not os.path.isfile(path):
        raise AdjustError(f"No such clip file: {path}")
    _enable(FORMATS[suffix])
    before = _ids()
    try:
        if suffix == ".bvh":
            _import_bvh(path, options)
        else:
            _import_fbx(path, options)
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
    _carry_longest_take(source, [i for i in added if isinstance(i, bpy.types.Action)])
    for action in (i for i in added if isinstance(i, bpy.types.Action)):
        action.name = f"{action.name} (source)"  # the clip's own name is for the action the retarget makes
    context.view_layer.update()
    return source, added


def _carry_longest_take(source, actions):
    """Make the longest of the clip's takes the armature's action. An FBX file may hold several (Kenney's and
    Mixamo's add a one-frame 'Targeting Pose' beside the motion) and Blender's importer leaves the first one active,
    which would carry a still pose instead of the clip. A take of one frame is a pose, not a clip; between takes of
    the same length the importer's choice stands."""
    anim = source.animation_data
    current = anim.action

    def length(action):
        start, end = action.frame_range
        return end - start

    longest = max(actions, key=length, default=current)
    if longest is not current and length(longest) > length(current):
        anim.action = longest
        # Blender 4.4+ keeps a slot only where the new action has one named as the old one was: 5.0's FBX importer
        # names every take's slot alike, 4.5's after its take, so the new take was left with no slot (unanimated)
        if bpy.app.version >= (4, 4, 0) and anim.action_slot is None and len(anim.action_suitable_slots):
            anim.action_slot = anim.action_suitable_slots[0]


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
