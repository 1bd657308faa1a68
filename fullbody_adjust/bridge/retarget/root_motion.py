# SPDX-License-Identifier: GPL-3.0-or-later
"""Writing a retarget with root motion (``retarget --root-motion``; the split is solver/retarget/root_motion):

    hips      (the default) the travel stays on the hips, as the solve left it;
    bone      the hips' horizontal travel and turn about the vertical go onto the root bone above them (an
              existing ancestor of the hips, or --root-bone NAME, created at the floor under the hips when the
              rig has no such bone; on a generated Rigify rig its 'root' control, the controls posed in place
              under it); the hips keep their height, tilt and sway relative to it;
    object    the same travel and turn on the armature object's location and rotation keys (in the same action);
    in-place  the travel and turn removed: the body stays over its rest place, facing its rest heading, swaying.

The root's travel and turn are the hips' ground path and heading smoothed over ``smoothing`` seconds
(``--root-smoothing``, default the solver's DEFAULT_SMOOTHING, a walking stride; times the scene's frame rate in
frames, solver root_motion.smooth): steady, the hips keeping their sway, the back-and-forth of each step and their
yaw wobble relative to the root; 0: the root follows the hips exactly (they keep only height and tilt). In ``bone``
and ``object`` every bone of the hips' hierarchy ends where the default puts it in the world, on every frame; bones
outside it (e.g. a game rig's IK bones under its root) follow the root. ``check`` refuses a bad request in one
line before the solve; ``write`` writes the retarget's pose (write.write_pose) and the root's keys.

An armature whose travel ``object`` keyed stands, for the next retarget onto it, where it stood before those keys
(``standing_basis``): retargeting again, in any mode, gives what the first run gave, not its travel added twice.
"""

from dataclasses import dataclass, replace

import bpy
import numpy as np
from mathutils import Matrix

from ...solver.retarget import motion as rt
from ...solver.retarget import root_motion as split
from ..errors import AdjustError
from ..rig import control_rig, mapping
from ..writing import keyframes
from .read import rig_of
from .write import write_pose

MODES = ("hips", "bone", "object", "in-place")
_CONTROL_ROOT = "root"  # the bone every control of a generated Rigify rig hangs from
_ROOT_LENGTH = 0.25  # a created root bone's length, in hips heights above the floor
# Set on an armature whose travel 'object' keyed: the action holding those keys and the object's matrix_basis they
# start from (row by row).
_STANDING = "fullbody_adjust_standing"


@dataclass(frozen=True)
class Request:
    """How the travel is written: ``mode`` (MODES), and for 'bone' the root bone's name, whether it is to be
    created, and whether it is a generated control rig's root control; ``smoothing``: seconds the root's path is
    smoothed over (0: the hips' exactly)."""

    mode: str = "hips"
    bone: str = None
    create: bool = False
    control: bool = False  # the root control of a generated control rig
    smoothing: float = split.DEFAULT_SMOOTHING


def check(target_obj, mode=None, root_bone=None, hips=None, smoothing=None):
    """The Request of ``mode``, ``root_bone`` and ``smoothing`` (seconds, None: the default) on
    ``target_obj``, whose hips bone is ``hips`` (default: its bone map's); AdjustError (one line) when it cannot be
    done, before anything changes."""
    mode = mode or "hips"
    if mode not in MODES:
        raise AdjustError(f"Unknown root motion '{mode}' (use {', '.join(MODES)})")
    if root_bone is not None and mode != "bone":
        raise AdjustError(f"A root bone ('{root_bone}') is for root motion 'bone', not '{mode}'")
    if smoothing is not None:
        if mode == "hips":
            raise AdjustError(f"A root smoothing ({smoothing:g} s) is for root motion 'bone', 'object' or "
                              f"'in-place', not 'hips'")
        if not 0.0 <= smoothing <= 1e6:  # NaN too
            raise AdjustError(f"The root smoothing must be 0 or more seconds, got {smoothing:g}")
    request = _request_of(target_obj, mode, root_bone, hips)
    return request if smoothing is None else replace(request, smoothing=float(smoothing))


def _request_of(target_obj, mode, root_bone, hips):
    if mode != "bone":
        return Request(mode)
    if control_rig.is_generated_rigify(target_obj):
        root = target_obj.pose.bones.get(_CONTROL_ROOT)
        if root is None or root.parent is not None or (root_bone or _CONTROL_ROOT) != _CONTROL_ROOT:
            raise AdjustError(f"On the generated control rig '{target_obj.name}' the travel goes on its "
                              f"'{_CONTROL_ROOT}' control" + ("" if root is not None and root.parent is None else
                                                              ", which it lacks (as a top bone)"))
        return Request("bone", _CONTROL_ROOT, control=True)
    hips = target_obj.data.bones[hips or mapping.read_map(target_obj).groups["root"][0]]
    above = hips.parent_recursive
    if root_bone is None:
        if not above:
            raise AdjustError(f"'{target_obj.name}' has no bone above its hips '{hips.name}': name the root bone to "
                              f"create (--root-bone NAME)")
        return Request("bone", above[-1].name)
    if not root_bone.strip():
        raise AdjustError("The root bone's name is empty")
    existing = target_obj.data.bones.get(root_bone)
    if existing is None:
        if target_obj.data.library is not None or target_obj.name not in bpy.context.view_layer.objects:
            raise AdjustError(f"Cannot add root bone '{root_bone}' to '{target_obj.name}': its armature is linked "
                              f"or not in the view layer")
        return Request("bone", root_bone, create=True)
    if existing not in above:
        raise AdjustError(f"Root bone '{root_bone}' is not above the hips '{hips.name}' of '{target_obj.name}' "
                          f"(bones above them: {', '.join(b.name for b in above) or 'none'})")
    return Request("bone", root_bone)


def add_requested_bone(context, target_obj, mode=None, root_bone=None, floor=None):
    """Create the root bone ``check`` asks to create, at ``floor`` (world height; None: the rig's lowest rest
    joint) as ``write`` does: a batch merging its clips' actions into one file needs it there (its workers create
    the same bone in their copies)."""
    request = check(target_obj, mode, root_bone)
    if request.create:
        _add_root_bone(context, target_obj, rig_of(target_obj, mapping.ensure_map(target_obj)), request.bone, floor)


def standing_basis(obj):
    """(4,4) the matrix_basis ``obj`` had before an earlier 'object' root motion keyed its travel, while its
    action is still that run's (its keys move it); else None."""
    record = obj.get(_STANDING)
    action = obj.animation_data.action if obj.animation_data is not None else None
    if record is None or action is None or action.name != record.get("action"):
        return None
    return np.array(record["basis"], dtype=np.float64).reshape(4, 4)


def record_standing(obj, action, basis):
    """Record that ``action`` keys ``obj``'s travel from the matrix_basis ``basis`` (4,4; None: nothing to record),
    for standing_basis: after an 'object' root motion, and after a partial retarget whose new action is a copy of
    one that did (the object's keys kept)."""
    if basis is not None:
        obj[_STANDING] = {"action": action.name, "basis": [float(v) for v in np.reshape(basis, -1)]}


def standing_world(obj):
    """(4,4) ``obj``'s world matrix where it stands for a retarget: its current one, or before an earlier
    'object' root motion's keys moved it (standing_basis)."""
    world = np.array(obj.matrix_world, dtype=np.float64)
    basis = standing_basis(obj)
    if basis is None:
        return world
    return world @ np.linalg.inv(np.array(obj.matrix_basis, dtype=np.float64)) @ basis


def write(context, request, target_obj, target, posed, frames, name, carried=(), floor=None):
    """write.write_pose of the retarget's pose ``posed`` (F,J,4,4, armature space of ``target``) as ``request``
    asks; ``floor``: the world height a created root bone stands at (None: the rig's lowest rest joint).
    Returns (action, keyed bones; the object's own keys in 'object' are not among them). An object an earlier
    'object' run moved goes back to where it stood (standing_basis), or its new keys start from there."""
    standing = standing_basis(target_obj)
    if standing is not None and (request is None or request.mode != "object"):
        target_obj.matrix_basis = Matrix(standing)  # the new action does not key the object: it stands there
        del target_obj[_STANDING]
    if request is None or request.mode == "hips":
        return write_pose(context, target_obj, target, posed, frames, name, carried)
    hips = target.groups["root"][0]
    world = target.matrix_world
    fps = context.scene.render.fps / context.scene.render.fps_base
    travel = split.split_travel(world @ posed[:, hips], world @ target.rest[hips], request.smoothing * fps)
    motion = split.in_armature_space(travel.matrices, world)  # (F,4,4), a left factor of armature-space poses
    if request.mode in ("object", "in-place") or request.control:
        body = target.descendants(hips)
        moved = posed.copy()
        moved[:, body] = split.residual(motion, posed[:, body])
        action, keyed = write_pose(context, target_obj, target, moved, frames, name, carried)
        if request.mode == "object":  # not a bone: not in ``keyed``
            _key_object(context, target_obj, action, frames, travel.matrices, standing)
        elif request.control:  # the controls posed in place under the root control, which takes the travel
            _key_control_root(context, target_obj, request.bone, motion, frames)
            keyed = keyed + (request.bone,)
        return action, keyed

    if request.create:
        old_names = target.names
        _add_root_bone(context, target_obj, target, request.bone, floor)
        target = rig_of(target_obj, mapping.ensure_map(target_obj))
        order = [old_names.index(n) if n in old_names else -1 for n in target.names]
        posed = np.where(np.array(order)[None, :, None, None] >= 0, posed[:, order], target.rest[None])
        carried = [target.names.index(old_names[c]) for c in carried]
        hips = target.groups["root"][0]
    root = target.names.index(request.bone)
    above = _ancestors(target.parents, hips)
    chain = above[:above.index(root) + 1]  # the root and the bones between it and the hips
    moved = posed.copy()
    moved[:, chain] = motion[:, None] @ posed[:, chain]
    action, keyed = write_pose(context, target_obj, target, moved, frames, name, carried)
    _key_root_bone(context, target_obj, target, moved, root, frames)
    return action, keyed + (request.bone,)


def _ancestors(parents, j):
    out = []
    while parents[j] >= 0:
        j = int(parents[j])
        out.append(j)
    return out


def _add_root_bone(context, target_obj, target, name, floor):
    """A new bone ``name`` at the floor under the hips' rest head, pointing up, parent of the hips' topmost
    bone."""
    hips = target.groups["root"][0]
    rest_world = target.to_world(target.rest[:, :3, 3])
    if floor is None:
        floor = float(rest_world[:, 2].min())
    head = np.array([rest_world[hips, 0], rest_world[hips, 1], floor])
    tail = head + (0.0, 0.0, _ROOT_LENGTH * max(rest_world[hips, 2] - floor, 1e-3 * target.scale))
    head, tail = target.to_armature(head), target.to_armature(tail)
    top = target.names[([hips] + _ancestors(target.parents, hips))[-1]]
    view_layer = context.view_layer
    active, mode = view_layer.objects.active, target_obj.mode
    try:
        view_layer.objects.active = target_obj
        bpy.ops.object.mode_set(mode='EDIT')
        bones = target_obj.data.edit_bones
        bone = bones.new(name)
        bone.head, bone.tail, bone.roll = head.tolist(), tail.tolist(), 0.0
        bones[top].parent = bone
        bones[top].use_connect = False
        bpy.ops.object.mode_set(mode='OBJECT' if mode == 'EDIT' else mode)
    except RuntimeError as ex:
        raise AdjustError(f"Cannot add root bone '{name}' to '{target_obj.name}': "
                          f"{' '.join(str(ex).split())}") from None
    finally:
        view_layer.objects.active = active


def _key_root_bone(context, target_obj, target, moved, root, frames):
    """Key the root bone's location and rotation (in its rotation mode) at its pose in ``moved``."""
    basis = rt.basis_from_pose(target, moved, [root])[:, 0]
    _key_bone_basis(context, target_obj, target_obj.pose.bones[target.names[root]], basis, frames)


def _key_control_root(context, target_obj, name, motion, frames):
    """Key a top bone's location and rotation so its pose is ``motion`` (F,4,4, armature space) @ its current
    one."""
    bone = target_obj.pose.bones[name]
    rest = np.array(bone.bone.matrix_local, dtype=np.float64)
    basis = np.linalg.inv(rest) @ motion @ rest @ np.array(bone.matrix_basis, dtype=np.float64)
    _key_bone_basis(context, target_obj, bone, basis, frames)


def _key_bone_basis(context, target_obj, bone, basis, frames):
    """Key a pose bone's location and rotation (in its rotation mode) at ``basis`` (F,4,4)."""
    prop = rt.ROTATION_PROPERTY[bone.rotation_mode]
    current = np.array(getattr(bone, prop), dtype=np.float64)[None]
    rotation = rt.rotation_channel(bone.rotation_mode, rt.unit_columns(basis[:, None, :3, :3]), current)[:, 0]
    keyframes.key_bones_frames(target_obj, None, frames, {bone.name: {"location": basis[:, :3, 3], prop: rotation}})
    context.scene.frame_set(context.scene.frame_current)


def _key_object(context, target_obj, action, frames, motions, standing=None):
    """Key the object's location and rotation so its world matrix is M @ the one it stands at on every frame
    (through its parent, if any): its current one, or ``standing`` (matrix_basis) where an earlier run's keys
    moved it; recorded for the next run (standing_basis)."""
    now = np.array(target_obj.matrix_basis, dtype=np.float64)
    basis0 = now if standing is None else standing
    outer = np.array(target_obj.matrix_world, dtype=np.float64) @ np.linalg.inv(now)  # parent and its inverse
    basis = np.linalg.inv(outer) @ motions @ outer @ basis0
    mode = target_obj.rotation_mode
    prop = rt.ROTATION_PROPERTY[mode]
    current = np.array(getattr(target_obj, prop), dtype=np.float64)[None]
    rotation = rt.rotation_channel(mode, rt.unit_columns(basis[:, None, :3, :3]), current)[:, 0]
    keyframes.key_object_frames(target_obj, action, frames, {"location": basis[:, :3, 3], prop: rotation})
    record_standing(target_obj, action, basis0)
    context.scene.frame_set(context.scene.frame_current)
