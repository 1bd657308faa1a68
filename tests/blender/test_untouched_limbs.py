"""Untouched means untouched, through the registered extension on the Rigify basic metarig made
to look like an imported character: sent through Blender's FBX exporter and importer, its arm and leg bones rolled
in edit mode (X axes that say nothing about how the limbs bend), turned to face -Y, +X, -X or +Y (transform
applied), and posed outside the default joint ranges (a leg raised past the hip cone, an elbow folded past the
hinge range) or with its elbows and knees straight (where only the rest pose tells the bend plane).

- A near Adjust Pose (the right hand's target within its arm's reach, the other targets where their effectors
  stand) keys only the right arm; every other bone's rotation relative to its parent stays within 0.01 degrees,
  with joint limits on as with them off.
- A far Adjust Pose (a hand target low in front of the feet: the pelvis comes down and the knees bend) moves each
  knee along the hips' line by no more than 1 cm.
- The metarig's own forearm and shin X axes, its true hinge axes, agree with the axes found at rest.

Every figure is measured on the pose Blender evaluates after the operator, against the pose before it.
"""

import math
from pathlib import Path

import bpy
import numpy as np
import pytest
from mathutils import Matrix, Vector

from .scene_tools import Pose, add_rig, animating_fcurves, bone_map, chain_joints, place, slot

HEADINGS = (0, 90, -90, 180)  # degrees about Z from the metarig's -Y: faces -Y, +X, -X, +Y
LIMBS = (("arm.L", "hand.L"), ("arm.R", "hand.R"), ("leg.L", "foot.L"), ("leg.R", "foot.R"))
SIDEWAYS = 0.01  # metres: the knees' allowance along the hips' line
UNCHANGED = 0.01  # degrees


def imported_rig(tmp_path, heading):
    """The basic metarig through FBX export and import (default options), arm and leg bones rolled by 40-180
    degrees, turned by ``heading`` degrees about Z with the rotation applied; active and mapped, with targets."""
    rig = add_rig("basic")
    path = Path(tmp_path) / "metarig.fbx"
    bpy.ops.export_scene.fbx(filepath=str(path), use_selection=True, object_types={'ARMATURE'})
    bpy.data.objects.remove(rig)
    bpy.ops.import_scene.fbx(filepath=str(path))
    obj = next(o for o in bpy.context.selected_objects if o.type == 'ARMATURE')
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    limb_bones = [b for b in obj.data.edit_bones if b.name.split(".")[0] in ("upper_arm", "forearm", "thigh", "shin")]
    for k, bone in enumerate(limb_bones):
        bone.roll += math.radians(40.0 + 20.0 * k)
    bpy.ops.object.mode_set(mode='OBJECT')
    obj.rotation_euler = (0.0, 0.0, math.radians(heading))
    bpy.context.view_layer.update()
    bpy.ops.object.transform_apply(location=False, rotation=True, scale=False)
    bpy.ops.fullbody_adjust.map_bones()
    bpy.ops.fullbody_adjust.create_targets()
    slot(obj, "head").enabled = False
    return obj


def facing(obj, pose):
    """Unit (up, left, forward) of the posed body in the world: left = right hip -> left hip, up = hips ->
    shoulders, forward = left x up."""
    groups = bone_map(obj)
    hips = [pose.world_heads[pose.index[groups[f"leg.{s}"][0]]] for s in "LR"]
    shoulders = [pose.world_heads[pose.index[groups[f"arm.{s}"][0]]] for s in "LR"]
    up = (shoulders[0] + shoulders[1] - hips[0] - hips[1]) / 2
    up /= np.linalg.norm(up)
    left = hips[0] - hips[1]
    left -= up * (left @ up)
    left /= np.linalg.norm(left)
    return up, left, np.cross(left, up)


def turn_bone(obj, name, axis, angle, pivot=None):
    """Turn pose bone ``name`` (and so everything below it) by ``angle`` radians about the armature-space
    ``axis`` through ``pivot`` (default its head)."""
    pb = obj.pose.bones[name]
    bpy.context.view_layer.update()
    pivot = Vector(pb.head if pivot is None else pivot)
    turn = Matrix.Translation(pivot) @ Matrix.Rotation(angle, 4, Vector(axis).normalized()) @ Matrix.Translation(-pivot)
    pb.matrix = turn @ pb.matrix
    bpy.context.view_layer.update()


def bend_angle(joints):
    u, v = joints[-2] - joints[-3], joints[-1] - joints[-2]
    return math.atan2(np.linalg.norm(np.cross(u, v)), float(u @ v))


def pose_outside_the_defaults(obj):
    """The left leg raised 125 degrees forward (past the default 115 degree hip cone) and the left elbow folded to
    2.95 rad (past the default 2.7)."""
    groups = bone_map(obj)
    up, left, forward = (np.linalg.inv(obj.matrix_world.to_3x3()) @ Vector(v) for v in facing(obj, Pose(obj)))
    turn_bone(obj, groups["leg.L"][0], left, -math.radians(125.0))
    arm = chain_joints(obj, Pose(obj), "arm.L")
    turn_bone(obj, groups["arm.L"][-1], np.cross(arm[-2] - arm[-3], arm[-1] - arm[-2]), 2.95 - bend_angle(arm))
    assert bend_angle(chain_joints(obj, Pose(obj), "arm.L")) == pytest.approx(2.95, abs=1e-4)


def straighten(obj):
    """Every elbow and knee straight: the forearm or shin swung onto its upper bone's direction."""
    for limb, _end in LIMBS:
        joints = chain_joints(obj, Pose(obj), limb)
        u, v = joints[-2] - joints[-3], joints[-1] - joints[-2]
        turn_bone(obj, bone_map(obj)[limb][-1], np.cross(v, u), math.atan2(np.linalg.norm(np.cross(u, v)), u @ v))
        assert bend_angle(chain_joints(obj, Pose(obj), limb)) < 1e-3


def local_rotations(obj, pose):
    """(B,3,3) each bone's rotation relative to its parent's (armature-space matrices, columns made unit)."""
    rot = pose.matrices[:, :3, :3] / np.linalg.norm(pose.matrices[:, :3, :3], axis=1, keepdims=True)
    out = rot.copy()
    for j, name in enumerate(pose.names):
        parent = obj.pose.bones[name].parent
        if parent is not None:
            out[j] = rot[pose.index[parent.name]].T @ rot[j]
    return out


def turned_degrees(obj, before, after):
    """(B,) degrees each bone turned relative to its parent (from the chord: exact for small angles in float32)."""
    change = np.einsum("bji,bjk->bik", local_rotations(obj, before), local_rotations(obj, after)) - np.eye(3)
    return np.degrees(2.0 * np.arcsin(np.minimum(np.linalg.norm(change, axis=(1, 2)) / (2.0 * math.sqrt(2.0)), 1.0)))


def keyed_bones(obj):
    return {fc.data_path.split('"')[1] for fc in animating_fcurves(obj) if fc.data_path.startswith("pose.bones")}


def near_right_hand(obj):
    """The right hand's target 20 % of the way from its wrist to its shoulder: within reach."""
    arm = chain_joints(obj, Pose(obj), "arm.R")
    place(slot(obj, "hand.R").target, Pose(obj).to_world(arm[-1] + 0.2 * (arm[0] - arm[-1])))


@pytest.mark.parametrize("use_limits", (True, False))
@pytest.mark.parametrize("heading", HEADINGS)
def test_a_near_target_keys_only_its_arm(tmp_path, heading, use_limits):
    obj = imported_rig(tmp_path, heading)
    pose_outside_the_defaults(obj)
    bpy.ops.fullbody_adjust.create_targets(reset=True)
    slot(obj, "head").enabled = False
    obj.fullbody_adjust.use_joint_limits = use_limits
    near_right_hand(obj)
    before = Pose(obj)
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    after = Pose(obj)
    groups = bone_map(obj)
    arm = set(groups["arm.R"] + groups["hand.R"])
    assert keyed_bones(obj) and keyed_bones(obj) <= arm
    angles = turned_degrees(obj, before, after)
    others = [j for j, name in enumerate(before.names) if name not in arm]
    worst = max(others, key=lambda j: angles[j])
    assert angles[worst] < UNCHANGED, (before.names[worst], angles[worst])


@pytest.mark.parametrize("heading", HEADINGS)
def test_a_far_target_bends_the_knees_without_swinging_them_sideways(tmp_path, heading, capfd):
    """Straight limbs, rolled X axes: the left hand's target low in front of the feet (the right hand free), feet
    planted: the pelvis comes down, the target is met, and each knee moves along the hips' line by < 1 cm."""
    obj = imported_rig(tmp_path, heading)
    straighten(obj)
    bpy.ops.fullbody_adjust.create_targets(reset=True)
    slot(obj, "head").enabled = False
    slot(obj, "hand.R").enabled = False
    before = Pose(obj)
    up, left, forward = facing(obj, before)
    groups = bone_map(obj)
    arm = chain_joints(obj, before, "arm.L")
    reach = float(np.linalg.norm(np.diff(before.to_world(arm), axis=0), axis=1).sum())
    feet = [before.world_heads[before.index[groups[f"foot.{s}"][0]]] for s in "LR"]
    goal = 0.5 * (feet[0] + feet[1]) + 0.4 * reach * forward + 0.1 * reach * up
    place(slot(obj, "hand.L").target, goal)
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    after = Pose(obj)
    wrist = after.world_heads[after.index[groups["hand.L"][0]]]
    assert np.linalg.norm(wrist - goal) < 1e-4
    root = before.index[groups["root"][0]]
    assert np.linalg.norm(after.world_heads[root] - before.world_heads[root]) > 0.1 * reach  # the pelvis came down
    for side in "LR":
        knee = before.index[groups[f"leg.{side}"][-1]]
        moved = after.world_heads[knee] - before.world_heads[knee]
        assert np.linalg.norm(moved) > 0.05 * reach  # the knee did bend
        assert abs(moved @ left) < SIDEWAYS, (side, moved @ left)


def test_the_metarigs_own_hinge_axes_agree_with_the_rest_ones():
    """Rigify's forearms and shins bend about their X axes: the axes the extension hands the solver (found at
    rest, carried by the upper bones) agree with them on the metarig at rest, the shins' exactly, the forearms'
    within the 11.6 degrees their roll sits off the arm's rest plane, posed as at rest or turned at the shoulder
    and hip."""
    from fullbody_adjust.bridge.reading import ik_limits
    from fullbody_adjust.bridge.reading import pose
    from fullbody_adjust.bridge.rig import rig_cache

    obj = add_rig("basic")
    bpy.ops.fullbody_adjust.map_bones()
    for turn in (0.0, 0.7):
        for limb, _end in LIMBS:
            turn_bone(obj, bone_map(obj)[limb][-2], (0.3, 1.0, 0.2), turn)
        rig = rig_cache.rig_of(obj)
        snapshot = pose.read_pose(obj, rig.static(obj))
        hints = ik_limits.hinge_hints(rig.model, snapshot.rest_matrices, snapshot.pose_matrices)
        current = Pose(obj)
        for limb, _end in LIMBS:
            lower = bone_map(obj)[limb][-1]
            joints = chain_joints(obj, current, limb)
            u = (joints[-2] - joints[-3]) / np.linalg.norm(joints[-2] - joints[-3])
            x = current.matrices[current.index[lower]][:3, 0]
            x = x - (x @ u) * u
            hint = hints[snapshot.index(lower)]
            hint = hint - (hint @ u) * u
            cos = abs(x @ hint) / np.linalg.norm(x) / np.linalg.norm(hint)
            angle = math.degrees(math.acos(min(cos, 1.0)))
            assert angle < (1e-3 if limb.startswith("leg") else 11.7), (limb, turn, angle)
