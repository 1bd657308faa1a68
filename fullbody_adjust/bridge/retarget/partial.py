# SPDX-License-Identifier: GPL-3.0-or-later
"""A partial retarget's action (``retarget --groups``): a copy of the target's own action, assigned to it, with the
F-Curves of the bones the retarget carries taken out (the retarget keys them afresh); every other bone keeps the
target's own F-Curves as they were, key for key. The groups' bones are solver.retarget.partial's."""

import re

import bpy

from ..errors import AdjustError
from ..rig import control_rig
from ..writing import keyframes

_LAYERED = "layers" in bpy.types.Action.bl_rna.properties  # 4.4+: slotted, layered actions
_BONE_OF_PATH = re.compile(r'^pose\.bones\["((?:[^"\\]|\\.)*)"\]')


def check_partial(target_obj):
    """AdjustError (one line) when a partial retarget cannot be written onto ``target_obj``."""
    if control_rig.is_generated_rigify(target_obj):
        raise AdjustError(f"'{target_obj.name}' is a generated control rig: retarget all of it (leave out --groups)")


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
