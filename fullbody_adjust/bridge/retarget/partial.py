# SPDX-License-Identifier: GPL-3.0-or-later
"""A partial retarget's action (``retarget --groups``): a copy of the target's own action, assigned to it, with the
F-Curves of the bones the retarget carries taken out (the retarget keys them afresh); every other bone keeps the
target's own F-Curves as they were, key for key. The groups' bones are solver.retarget.partial's.

The object's own keys are kept too (an earlier 'object' root motion's travel, or the user's): where they move it,
the carried bones are keyed so that they end in the world where the solve put them, the object moving under them
(``own_motion``), not with its travel added to the solve's."""

import re

import bpy
import numpy as np

from ..errors import AdjustError
from ..reading import pose
from ..rig import control_rig
from ..writing import keyframes
from .read import read_motion

_LAYERED = "layers" in bpy.types.Action.bl_rna.properties  # 4.4+: slotted, layered actions
_BONE_OF_PATH = re.compile(r'^pose\.bones\["((?:[^"\\]|\\.)*)"\]')


def check_partial(target_obj):
    """AdjustError (one line) when a partial retarget cannot be written onto ``target_obj``."""
    if control_rig.is_generated_rigify(target_obj):
        raise AdjustError(f"'{target_obj.name}' is a generated control rig: retarget all of it (leave out --groups)")


def own_motion(obj, rig, frames):
    """The target's own motion at ``frames``, read before a partial retarget replaces its action: (pose matrices
    (F,J,4,4) in its armature space, and where its object moves over the frames, how: (F,4,4) left factors taking
    the armature space of ``rig``'s world matrix, which the solve works in, to the object's on each frame; else
    None). A pose solved in ``rig``'s space keyed as solver.retarget.root_motion.residual of it ends in the world
    where solved, the object moving under it: only the topmost bones' keys change (a common left factor leaves
    every bone's local transform under its parent as it was)."""
    moved = obj.parent is not None or any(c.enabled for c in obj.constraints) or any(
        not fc.data_path.startswith("pose.bones[") for fc in keyframes.animating_fcurves(obj))
    if not moved:
        return read_motion(obj, rig, frames)[0], None
    snapshot = pose.read_pose_frames(obj, frames)
    worlds = np.asarray(snapshot.matrix_world, dtype=np.float64)
    still = np.all(worlds == worlds[:1])
    return snapshot.pose_matrices, (None if still else np.linalg.inv(rig.matrix_world) @ worlds)


def action_without(obj, name, bone_names):
    """A copy of ``obj``'s action (an empty one when it has none) named ``name`` and assigned to it (the
    original is kept), without the F-Curves of ``bone_names``."""
    anim = obj.animation_data or obj.animation_data_create()
    original = anim.action
    slot = anim.action_slot.identifier if _LAYERED and anim.action_slot else None
    action = original.copy() if original is not None else bpy.data.actions.new(name)
    action.name = name  # Blender adds .001 when the name is taken (by the original too)
    keyframes.assign_action(obj, action)
    if slot and anim.action_slot is None and slot in action.slots:  # the copy has the same slots
        anim.action_slot = action.slots[slot]
    removed = set(bone_names)
    for curves in _curve_collections(obj, action):
        for fcurve in [fc for fc in curves if _bone_of(fc.data_path) in removed]:
            curves.remove(fcurve)
    return action


def _curve_collections(obj, action):
    """The F-Curve collections of ``action`` that animate ``obj``: the action's own (4.2), the slot's channelbag
    (4.4+; none before a slot is assigned)."""
    if not _LAYERED:
        return [action.fcurves]
    slot = obj.animation_data.action_slot
    if slot is None:
        return []
    from bpy_extras import anim_utils
    bag = anim_utils.action_get_channelbag_for_slot(action, slot)
    return [bag.fcurves] if bag is not None else []


def _bone_of(data_path):
    match = _BONE_OF_PATH.match(data_path)
    return None if match is None else match.group(1).replace('\\"', '"').replace("\\\\", "\\")
