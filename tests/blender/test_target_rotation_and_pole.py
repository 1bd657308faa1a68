"""Per-slot ``use_rotation`` (the hand or foot takes its target's world orientation) and ``pole`` (the elbow or
knee bends toward a pole object), through bpy.ops.fullbody_adjust.adjust_pose on a moved and rotated rig."""

import bpy
import numpy as np
import pytest
from mathutils import Euler, Matrix

from .scene_tools import Pose, add_rig, body_axes, bone_map, chain_joints, chain_length, effector_bone, place, \
    residuals, slot

REACH = 1e-4  # a met target is within this fraction of the rig's height


def _turned_rig():
    obj = add_rig("basic")
    obj.matrix_world = Matrix.Translation((0.4, -0.3, 0.1)) @ Euler((0.0, 0.0, 0.6)).to_matrix().to_4x4()
    bpy.ops.fullbody_adjust.create_targets()
    return obj


def _unit(m):
    m = np.asarray(m, dtype=np.float64)[:3, :3]
    return m / np.linalg.norm(m, axis=0)


def _angle(a, b):
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0))))


def _hand_world_rotation(obj, effector):
    bpy.context.view_layer.update()
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    return _unit(np.array(ev.matrix_world) @ np.array(ev.pose.bones[effector_bone(obj, effector)].matrix))


def _reach_point(obj, pose, group, fraction, *offsets):
    joints = chain_joints(obj, pose, group)
    direction = (joints[-1] - joints[0]) / np.linalg.norm(joints[-1] - joints[0]) + sum(offsets)
    return joints[0] + fraction * chain_length(joints) * direction / np.linalg.norm(direction)


@pytest.mark.parametrize("degrees", [0.0, 35.0])
@pytest.mark.parametrize("effector, group", [("hand.L", "arm.L"), ("foot.R", "leg.R")])
def test_the_hand_or_foot_takes_its_targets_world_orientation(effector, group, degrees):
    obj = _turned_rig()
    pose = Pose(obj)
    up, left, forward = body_axes(obj, pose)
    goal = _reach_point(obj, pose, group, 0.85, 0.3 * forward)
    target = slot(obj, effector).target
    place(target, pose.to_world(goal))
    # The target turned from the hand's current world orientation about a tilted axis.
    turn = np.array(Matrix.Rotation(np.radians(degrees), 3, (0.3, 0.8, 0.5)))
    wanted = turn @ _hand_world_rotation(obj, effector)
    world = np.eye(4)
    world[:3, :3], world[:3, 3] = wanted, pose.to_world(goal)
    target.matrix_world = Matrix(world.tolist())
    slot(obj, effector).use_rotation = True
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    assert residuals(obj)[effector] < REACH * Pose(obj).height()
    assert _angle(_hand_world_rotation(obj, effector), wanted) < 0.5


def test_without_use_rotation_the_hand_keeps_its_world_orientation():
    obj = _turned_rig()
    pose = Pose(obj)
    before = _hand_world_rotation(obj, "hand.L")
    target = slot(obj, "hand.L").target
    target.rotation_euler = (0.9, 0.2, -0.4)
    place(target, pose.to_world(_reach_point(obj, pose, "arm.L", 0.85, 0.3 * body_axes(obj, pose)[2])))
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    assert _angle(_hand_world_rotation(obj, "hand.L"), before) < 0.05


def test_a_target_turned_beyond_the_wrist_is_followed_only_as_far_as_the_wrist_bends():
    obj = _turned_rig()
    pose = Pose(obj)
    goal = _reach_point(obj, pose, "arm.L", 0.85, 0.3 * body_axes(obj, pose)[2])
    target = slot(obj, "hand.L").target
    start = _hand_world_rotation(obj, "hand.L")
    # Pointing the hand back along the forearm: no wrist bends that far.
    forearm = pose.to_world(chain_joints(obj, pose, "arm.L")[-1]) - pose.to_world(chain_joints(obj, pose, "arm.L")[-2])
    flip = np.array(Matrix.Rotation(np.radians(170.0), 3, tuple(np.cross(forearm, start[:, 0]))))
    world = np.eye(4)
    world[:3, :3], world[:3, 3] = flip @ start, pose.to_world(goal)
    target.matrix_world = Matrix(world.tolist())
    slot(obj, "hand.L").use_rotation = True
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    after = Pose(obj)
    joints = after.to_world(chain_joints(obj, after, "arm.L"))
    hand = _hand_world_rotation(obj, "hand.L")[:, 1]  # the hand bone's direction
    forearm_now = (joints[-1] - joints[-2]) / np.linalg.norm(joints[-1] - joints[-2])
    start_bend = np.degrees(np.arccos(np.clip(start[:, 1] @ forearm / np.linalg.norm(forearm), -1, 1)))
    bend = np.degrees(np.arccos(np.clip(hand @ forearm_now, -1.0, 1.0)))
    assert bend <= start_bend + 80.0 + 0.5


# Largest angle (degrees) between the elbow's or knee's side and the pole's about the line root -> target: in the
# pole's plane where the joint limits allow it; a knee turned fully out is held by the hip's limits, still on the
# pole's side.
@pytest.mark.parametrize("effector, group, side, within", [
    ("hand.L", "arm.L", "down", 2.0), ("hand.L", "arm.L", "back", 2.0), ("foot.L", "leg.L", "forward", 2.0),
    ("foot.L", "leg.L", "left", 90.0)])
def test_the_elbow_or_knee_bends_toward_its_pole(effector, group, side, within):
    obj = _turned_rig()
    pose = Pose(obj)
    up, left, forward = body_axes(obj, pose)
    offsets = {"down": -up, "back": -forward, "forward": forward, "left": left}
    goal = _reach_point(obj, pose, group, 0.7, 0.4 * forward)
    place(slot(obj, effector).target, pose.to_world(goal))
    base = chain_joints(obj, pose, group)[-3]  # shoulder or hip
    pole_point = base + 0.5 * (goal - base) + 0.6 * chain_length(chain_joints(obj, pose, group)) * offsets[side]
    pole = bpy.data.objects.new("Pole", None)
    bpy.context.scene.collection.objects.link(pole)
    pole.location = tuple(pose.to_world(pole_point))
    slot(obj, effector).pole = pole
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    after = Pose(obj)
    assert residuals(obj)[effector] < REACH * after.height()
    joints = chain_joints(obj, after, group)
    root, middle, end = joints[-3], joints[-2], joints[-1]
    along = (end - root) / np.linalg.norm(end - root)

    def across(point):
        v = point - root
        v = v - along * (v @ along)
        return v / np.linalg.norm(v)

    # On the pole's side of the line root -> target, in the plane root, target, pole.
    assert np.degrees(np.arccos(np.clip(across(middle) @ across(pole_point), -1.0, 1.0))) < within


def test_a_pole_that_left_the_scene_is_one_line_error():
    obj = _turned_rig()
    pole = bpy.data.objects.new("GonePole", None)
    slot(obj, "hand.L").pole = pole
    with pytest.raises(RuntimeError, match="Pole 'GonePole' for hand.L is missing from the scene"):
        bpy.ops.fullbody_adjust.adjust_pose()


@pytest.mark.parametrize("limbs,keep_hands", [("IK", True), ("FK", True), ("IK", False), ("FK", False)])
def test_a_generated_rigify_hand_takes_its_targets_orientation_through_the_controls(limbs, keep_hands):
    """Also with Keep Hand Orientation off: the other hands follow their forearms, this one its target."""
    from .test_rigify import generated_rig

    rig = generated_rig("basic", limbs)
    rig.fullbody_adjust.keep_hand_orientation = keep_hands
    pose = Pose(rig)
    goal = _reach_point(rig, pose, "arm.L", 0.85, 0.3 * body_axes(rig, pose)[2])
    target = slot(rig, "hand.L").target
    wanted = np.array(Matrix.Rotation(np.radians(30.0), 3, (0.2, 0.9, 0.4))) @ _hand_world_rotation(rig, "hand.L")
    world = np.eye(4)
    world[:3, :3], world[:3, 3] = wanted, pose.to_world(goal)
    target.matrix_world = Matrix(world.tolist())
    slot(rig, "hand.L").use_rotation = True
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    # The mesh follows the deform bone.
    bpy.context.view_layer.update()
    ev = rig.evaluated_get(bpy.context.evaluated_depsgraph_get())
    deform = _unit(np.array(ev.matrix_world) @ np.array(ev.pose.bones["DEF-hand.L"].matrix))
    assert _angle(deform, wanted) < 0.5
