"""What a command-line run needs from Blender besides the adjustment itself: opening and saving .blend files,
choosing the armature and the frame range, and reading skeletons, targets and obstacle boxes for the preview
picture. Every problem is an AdjustError with one line, raised before anything is changed."""

import math
import os

import bpy
import numpy as np

from ..solver.body.joint_ends import end_points, joint_ends
from .rig import mapping, targets
from .reading import obstacles, pose
from .errors import AdjustError


def open_blend(path):
    """Open ``path`` as the current file (without running scripts stored in it)."""
    if not os.path.exists(path):
        raise AdjustError(f"No such file: {path}")
    if os.path.isdir(path):
        raise AdjustError(f"{path} is a folder, not a .blend file")
    if not os.access(path, os.R_OK):
        raise AdjustError(f"Cannot read {path}: permission denied")
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False, use_scripts=False)
    except RuntimeError as ex:
        raise AdjustError(f"Cannot open {path}: {_blender_message(ex)}") from None


def current_file():
    """Path of the open .blend file ('' when it was never saved)."""
    return bpy.data.filepath


def save_blend(path):
    """Save the current data as ``path`` (a copy: the open file keeps its own path). The file's own
    compression setting is kept."""
    try:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(path), copy=True)
    except RuntimeError as ex:
        raise AdjustError(f"Cannot save {path}: {_blender_message(ex)}") from None


def write_datablocks(path, datablocks):
    """Write only ``datablocks`` (and what they use) into a new .blend at ``path``, with fake users."""
    try:
        bpy.data.libraries.write(os.path.abspath(path), set(datablocks), fake_user=True)
    except (OSError, RuntimeError) as ex:
        raise AdjustError(f"Cannot write {path}: {_blender_message(ex)}") from None


def append_datablocks(context, path):
    """Append the actions and objects of the .blend at ``path`` (written by write_datablocks) into the current
    file: the actions keep a fake user, the objects join the scene. Returns {name in that file: appended
    action} (an appended action is renamed when the current file has one of its name)."""
    with bpy.data.libraries.load(os.path.abspath(path), link=False) as (data_from, data_to):
        names = list(data_from.actions)
        data_to.actions = list(names)
        data_to.objects = list(data_from.objects)
    for action in data_to.actions:
        action.use_fake_user = True
    for obj in data_to.objects:
        context.scene.collection.objects.link(obj)
    return dict(zip(names, data_to.actions))


def armature_named(context, name, option="--armature"):
    """The armature object ``name`` of the current scene; AdjustError naming the scene's armatures otherwise."""
    scene = context.scene
    obj = scene.objects.get(name)
    if obj is None:
        raise AdjustError(f"{option}: no object named '{name}' in scene '{scene.name}' "
                          f"(armatures: {_names(scene_armatures(scene))})")
    if obj.type != 'ARMATURE':
        raise AdjustError(f"{option}: '{name}' is a {obj.type.lower()}, not an armature "
                          f"(armatures: {_names(scene_armatures(scene))})")
    return obj


def object_named(context, name, option):
    obj = context.scene.objects.get(name)
    if obj is None:
        raise AdjustError(f"{option}: no object named '{name}' in scene '{context.scene.name}'")
    return obj


def scene_armatures(scene):
    return sorted((ob for ob in scene.objects if ob.type == 'ARMATURE'), key=lambda ob: ob.name)


def has_targets(obj):
    """True when an enabled target slot of ``obj`` points at an object."""
    return any(slot.enabled and slot.target is not None for slot in obj.fullbody_adjust.targets)


def default_armature(context):
    """The only armature of the scene with targets set; else the active object when it is an armature; else the
    only armature. AdjustError when that is ambiguous or there is none."""
    scene = context.scene
    armatures = scene_armatures(scene)
    with_targets = [ob for ob in armatures if has_targets(ob)]
    if len(with_targets) == 1:
        return with_targets[0]
    if len(with_targets) > 1:
        raise AdjustError(f"Several armatures have targets ({_names(with_targets)}): choose one with --armature")
    active = context.view_layer.objects.active
    if active is not None and active.type == 'ARMATURE':
        return active
    if len(armatures) == 1:
        return armatures[0]
    if not armatures:
        raise AdjustError(f"Scene '{scene.name}' has no armature")
    raise AdjustError(f"No armature has targets set and several exist ({_names(armatures)}): choose one with "
                      f"--armature")


def check_mappable(obj, option):
    """AdjustError (one line, naming ``option``) unless ``obj``'s stored bone map fits it or its bones can be
    mapped onto the body model (a map the user typed is checked, never replaced: mapping.read_map). Changes
    nothing."""
    try:
        mapping.read_map(obj)
    except mapping.MappingError as ex:
        raise AdjustError(f"{option} '{obj.name}' cannot be mapped: {ex}") from None


def frame_range(obj, scene, start=None, end=None, within_scene=False):
    """(start, end) frames of a run on ``obj``: by default the range of its action (its manual frame range when
    set; ``within_scene``: only its part within the scene's frame range, when they overlap), or the scene's when
    it has none. A given range must lie within the action."""
    action = obj.animation_data.action if obj.animation_data is not None else None
    if action is not None:
        lo, hi = action.frame_range
        lo, hi = int(math.ceil(lo - 1e-6)), int(math.floor(hi + 1e-6))
    else:
        lo, hi = scene.frame_start, scene.frame_end
    first, last = lo, hi
    if within_scene and max(lo, scene.frame_start) <= min(hi, scene.frame_end):
        first, last = max(lo, scene.frame_start), min(hi, scene.frame_end)
    start = first if start is None else int(start)
    end = last if end is None else int(end)
    if end < start:
        raise AdjustError(f"Frame range {start}..{end} is empty (the end is before the start)")
    if action is not None and (start < lo or end > hi):
        raise AdjustError(f"Frame range {start}..{end} lies outside action '{action.name}' of '{obj.name}' "
                          f"(frames {lo}..{hi})")
    return start, end


# Bytes a frame range needs per bone and frame, roughly: the pose, solve and write arrays hold about eight
# 4x4 float64 matrices for each.
BYTES_PER_BONE_FRAME = 8 * 16 * 8


def check_frame_budget(context, obj, start, end):
    """AdjustError (one line) before any work when [start, end] reaches far beyond every key of the scene's
    animation and its frame range (more than that span again, and 100 frames), or when its arrays would not
    fit in half the memory available."""
    scene = context.scene
    lo, hi = scene.frame_start, scene.frame_end
    for ob in scene.objects:
        action = ob.animation_data.action if ob.animation_data is not None else None
        if action is not None:
            lo, hi = min(lo, int(math.floor(action.frame_range[0]))), max(hi, int(math.ceil(action.frame_range[1])))
    slack = max(hi - lo + 1, 100)
    if start < lo - slack or end > hi + slack:
        raise AdjustError(f"Frame range {start}..{end} reaches far beyond the animation (keys and scene range: "
                          f"frames {lo}..{hi}): give a range near it")
    need = (end - start + 1) * len(obj.data.bones) * BYTES_PER_BONE_FRAME
    free = available_memory()
    if free is not None and need > free / 2:
        raise AdjustError(f"Frame range {start}..{end} would need about {need / 2**30:.1f} GiB for "
                          f"{len(obj.data.bones)} bones, more than half the {free / 2**30:.1f} GiB available: "
                          f"split it into shorter ranges")


def available_memory():
    """Bytes of physical memory available now (None where the system does not say)."""
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def action_name(obj):
    action = obj.animation_data.action if obj.animation_data is not None else None
    return None if action is None else action.name


def stored_settings(obj):
    """The solver settings stored on the armature, by Options field name (floats as the float32 Blender stores,
    printed short: 0.01, not 0.009999999776)."""
    stored = obj.fullbody_adjust
    values = {name: getattr(stored, name) for name in ("variant", "margin", "tolerance", "max_iterations",
                                                       "use_joint_limits", "keep_hand_orientation")}
    return {name: float(f"{value:.7g}") if isinstance(value, float) else value for name, value in values.items()}


# --- for the preview -----------------------------------------------------------------------------------------

def skeleton_segments(obj, frames):
    """World (head, end) of the armature's deforming bones (every bone when none deforms) at each frame:
    (F, M, 2, 3). A bone is drawn to where it ends as a joint (solver.joint_ends), not to its tail, which an
    importer may have left far past the next joint."""
    snapshot = pose.read_pose_frames(obj, frames)
    bones = obj.data.bones
    ends = joint_ends(snapshot.parents, snapshot.rest_matrices, pose.rest_tails(obj))
    world = snapshot.matrix_world[:, None] @ snapshot.pose_matrices
    deform = np.array([bone.use_deform for bone in bones], dtype=bool)
    keep = deform if deform.any() else np.ones(len(deform), dtype=bool)
    return np.stack([snapshot.heads[:, keep], end_points(world, ends)[:, keep]], axis=2)


def effector_positions(obj, frames):
    """World positions (F, len(EFFECTORS), 3) of the effector joints (heads of the mapped hand, foot and head
    bones; an arm without a hand bone: where its last bone ends, solver.joint_ends) at each frame; NaN for an
    effector the map does not have."""
    bone_map = mapping.ensure_map(obj)
    snapshot = pose.read_pose_frames(obj, frames)
    out = np.full((len(snapshot.frame), len(targets.EFFECTORS), 3), np.nan)
    handless = bone_map.handless()
    ends = joint_ends(snapshot.parents, snapshot.rest_matrices, pose.rest_tails(obj)) if handless else None
    for column, effector in enumerate(targets.EFFECTORS):
        bones = bone_map.bones(effector)  # the hand, foot and head groups are named after their effectors
        if bones:
            out[:, column] = snapshot.heads[:, snapshot.index(bones[-1])]
        elif effector in handless:
            j = snapshot.index(handless[effector])
            out[:, column] = end_points(snapshot.matrices[:, j], ends[j])
    return out


def target_positions(context, obj, frames):
    """World target positions (F, len(EFFECTORS), 3), NaN where an effector has no enabled target."""
    return targets.read_target_frames(obj, frames, context)


def obstacle_extents(context, obj, frames):
    """(F, K, 2, 3) min and max world corner of each obstacle box at each frame."""
    corners = obstacles.obstacle_box_frames(obj, context, frames)
    return np.stack([corners.min(axis=2), corners.max(axis=2)], axis=2)


def _names(objects):
    return ", ".join(f"'{ob.name}'" for ob in objects) or "none"


def _blender_message(ex):
    """Blender's operator error without its 'Error: ' prefix, on one line."""
    text = " ".join(str(ex).split())
    return text[len("Error: "):] if text.startswith("Error: ") else text
