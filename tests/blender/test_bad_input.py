"""Bad input to the adjust operators: each gives one clear line (the operator raises RuntimeError
when called from Python) and leaves the file exactly as it was: objects, transforms, poses (also pose changes
not keyed yet), keys, settings, actions.

The scene: the basic metarig mapped, with targets, keys at frames 1 and 10 and an unkeyed pose change at the
current frame; each case then spoils one thing.
"""

import math

import bpy
import pytest

from .scene_tools import add_rig, add_single_bone_armature, file_state, slot

OPERATORS = {
    "adjust_pose": lambda: bpy.ops.fullbody_adjust.adjust_pose(),
    "adjust_frames": lambda: bpy.ops.fullbody_adjust.adjust_frames(frame_start=1, frame_end=10),
}


def keyed_rig():
    obj = add_rig("basic")
    bpy.ops.fullbody_adjust.create_targets()
    forearm = obj.pose.bones["forearm.L"]
    for frame, angle in ((1, 0.1), (10, 0.6)):
        forearm.rotation_quaternion = (math.cos(angle), math.sin(angle), 0.0, 0.0)
        forearm.keyframe_insert("rotation_quaternion", frame=frame)
    bpy.context.scene.frame_set(5)
    forearm.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)  # posed, not keyed: must survive a failed run
    return obj


def link_from_library(obj, tmp_path, kind):
    """Save the file as a library, start an empty file and link the keyed rig's object, or only its action
    (assigned to a new local rig), from it."""
    library = tmp_path / "library.blend"
    names = {"objects": [obj.name], "actions": [obj.animation_data.action.name]}
    bpy.ops.wm.save_as_mainfile(filepath=str(library), copy=True)
    bpy.ops.wm.read_homefile(use_empty=True)  # `obj` is gone from here on
    with bpy.data.libraries.load(str(library), link=True) as (source, linked):
        setattr(linked, kind + "s", names[kind + "s"])
    if kind == "object":
        obj = linked.objects[0]
        bpy.context.scene.collection.objects.link(obj)
    else:
        obj = add_rig("basic")
        bpy.ops.fullbody_adjust.create_targets()
        action = linked.actions[0]
        obj.animation_data_create().action = action
        if hasattr(action, "slots") and obj.animation_data.action_slot is None:
            obj.animation_data.action_slot = action.slots[0]
        assert action.library is not None
    bpy.context.view_layer.objects.active = obj


def no_active_object(obj, tmp_path):
    bpy.context.view_layer.objects.active = None


def mesh_active(obj, tmp_path):
    bpy.ops.mesh.primitive_cube_add()


def single_bone(obj, tmp_path):
    add_single_bone_armature("Stick", bones=1)


def bone_chain(obj, tmp_path):
    add_single_bone_armature("Snake", bones=6)


def no_enabled_target(obj, tmp_path):
    for s in obj.fullbody_adjust.targets:
        s.enabled = False


def no_target_slots(obj, tmp_path):
    obj.fullbody_adjust.targets.clear()


def target_deleted(obj, tmp_path):
    """Deleted in the viewport: the slot still points at it, but it is in no scene."""
    bpy.ops.object.select_all(action='DESELECT')
    slot(obj, "hand.L").target.select_set(True)
    bpy.ops.object.delete()
    bpy.context.view_layer.objects.active = obj


def target_removed(obj, tmp_path):
    """Removed from the file (e.g. by a script or a purge): the slot is empty but still enabled."""
    bpy.data.objects.remove(slot(obj, "foot.R").target)


def target_nan(obj, tmp_path):
    slot(obj, "hand.R").target.location.y = math.nan


def target_inf(obj, tmp_path):
    """Blender stores an infinite location as the largest float (3.4e38): far beyond anything reachable."""
    slot(obj, "foot.L").target.location.z = -math.inf


def target_inf_in_world(obj, tmp_path):
    """Finite settings whose world location overflows: parented under a huge scale."""
    parent = bpy.data.objects.new("Huge", None)
    bpy.context.scene.collection.objects.link(parent)
    parent.scale = (1e30, 1e30, 1e30)
    target = slot(obj, "hand.L").target
    target.parent = parent
    target.location = (1e10, 0.0, 0.0)


def bone_scaled_to_zero(obj, tmp_path):
    """Blender deletes zero-length bones on leaving Edit Mode; the user gets one by scaling a bone to 0 in Pose
    Mode (here the forearm: the wrist then sits on the elbow)."""
    obj.pose.bones["forearm.L"].scale = (0.0, 0.0, 0.0)


def bone_flattened(obj, tmp_path):
    """Scaled to 0 along its length only: the bone has no length and its children collapse onto its head."""
    obj.pose.bones["thigh.R"].scale = (1.0, 0.0, 1.0)


def negative_scale(obj, tmp_path):
    obj.scale.x = -1.0


def zero_scale(obj, tmp_path):
    obj.scale = (0.0, 0.0, 0.0)


def mirrored_parent(obj, tmp_path):
    parent = bpy.data.objects.new("Mirror", None)
    bpy.context.scene.collection.objects.link(parent)
    parent.scale.z = -1.0
    obj.parent = parent


def linked_armature(obj, tmp_path):
    link_from_library(obj, tmp_path, "object")


def linked_action(obj, tmp_path):
    link_from_library(obj, tmp_path, "action")


def edit_mode(obj, tmp_path):
    bpy.ops.object.mode_set(mode='EDIT')


# case -> (how to spoil the scene, what the one line says)
CASES = {
    "no_active_object": (no_active_object, "No active object: select an armature"),
    "mesh_active": (mesh_active, "'Cube' is not an armature"),
    "single_bone": (single_bone, "Cannot map rig 'Stick': no "),
    "bone_chain": (bone_chain, "Cannot map rig 'Snake': no "),
    "no_enabled_target": (no_enabled_target, "No enabled target"),
    "no_target_slots": (no_target_slots, "No enabled target"),
    "target_deleted": (target_deleted, "Target 'metarig_hand.L' for hand.L is missing from the scene (deleted?)"),
    "target_removed": (target_removed, "Target for foot.R is missing (deleted?)"),
    "target_nan": (target_nan, "Target 'metarig_hand.R' for hand.R has a non-finite location"),
    "target_inf": (target_inf, "Target 'metarig_foot.L' for foot.L is 3.4e+38 units away, too far to reach for"),
    "target_inf_in_world": (target_inf_in_world, "Target 'metarig_hand.L' for hand.L has a non-finite location"),
    "bone_scaled_to_zero": (bone_scaled_to_zero, "Bone 'forearm.L' has zero length or scale"),
    "bone_flattened": (bone_flattened, "Bone 'thigh.R' has zero length or scale"),
    "negative_scale": (negative_scale, "Armature 'metarig' has a negative or zero scale"),
    "zero_scale": (zero_scale, "Armature 'metarig' has a negative or zero scale"),
    "mirrored_parent": (mirrored_parent, "Armature 'metarig' has a negative or zero scale"),
    "linked_armature": (linked_armature, "Armature 'metarig' is linked from library 'library.blend'"),
    "linked_action": (linked_action, "Action 'metarigAction' of 'metarig' is linked from library 'library.blend' "
                                     "and cannot be keyed"),
    "edit_mode": (edit_mode, "Switch to Object or Pose Mode"),
}


@pytest.mark.parametrize("operator", OPERATORS)
@pytest.mark.parametrize("case", CASES)
def test_bad_input_reports_one_line_and_changes_nothing(case, operator, tmp_path):
    spoil, message = CASES[case]
    spoil(keyed_rig(), tmp_path)
    bpy.context.view_layer.update()
    before = file_state()

    with pytest.raises(RuntimeError) as raised:
        OPERATORS[operator]()

    text = str(raised.value).strip()
    assert message in text
    assert "\n" not in text and "Traceback" not in text
    assert file_state() == before


def test_unmapped_bone_scaled_to_zero_is_no_error(capfd):
    """A bone outside the body model (here Rigify's heel) may be scaled away: it only follows its parent."""
    obj = keyed_rig()
    obj.pose.bones["heel.02.L"].scale = (0.0, 0.0, 0.0)
    slot(obj, "hand.L").target.location.z += 0.1

    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    assert "4 of 4 targets met" in capfd.readouterr().out
    assert tuple(obj.pose.bones["heel.02.L"].scale) == (0.0, 0.0, 0.0)
