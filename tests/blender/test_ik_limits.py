"""The rig's own joint limits through the registered extension (Adjust Pose / Adjust Frames) on the Rigify basic
human metarig: a forearm's IK locks, its IK range and a LOCAL Limit Rotation constraint hold on every frame,
measured on the pose Blender evaluates (or, for the constraint, on the channels the operator keyed, since the
constraint clamps the evaluated pose by itself), and a rig that sets nothing is solved exactly as before.
"""

import importlib
import math

import bpy
import numpy as np
import pytest

from .scene_tools import Pose, add_rig, body_axes, chain_joints, chain_length, pose_channels, place, slot

FRAMES = 5
# Blender's pose is float32: an angle read back from it is good to a few 1e-6 rad.
ANGLE = 1e-4
X_RANGE = (-0.15, 0.2)  # radians about the forearm's X axis, from its rest


def rig_with_goals():
    """The basic metarig with targets; the left hand's target keyed on frames 1..FRAMES at goals around the
    shoulder, in front and to the side, which the free elbow reaches by bending a lot; the other targets stay
    at the rest pose's wrists and ankles."""
    obj = add_rig("basic")
    bpy.ops.fullbody_adjust.create_targets()
    pose = Pose(obj)
    up, left, forward = body_axes(obj, pose)
    arm = chain_joints(obj, pose, "arm.L")
    shoulder, reach = arm[1], chain_length(arm[1:])
    directions = [forward, forward + up, left + forward, -up + 0.3 * forward, left - 0.2 * up]
    target = slot(obj, "hand.L").target
    for frame, (distance, direction) in enumerate(zip((0.45, 0.5, 0.7, 0.55, 0.98), directions), start=1):
        place(target, pose.to_world(shoulder + distance * reach * direction / np.linalg.norm(direction)))
        target.keyframe_insert("location", frame=frame)
    bpy.context.scene.frame_set(1)
    return obj


def adjust_frames(obj):
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.fullbody_adjust.adjust_frames(frame_start=1, frame_end=FRAMES) == {'FINISHED'}


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def forearm_in_rest_frame(obj, pose):
    """The evaluated forearm's direction in its rest frame carried by the evaluated upper arm (Blender's IK
    measure: at rest it is +Y)."""
    bones = obj.data.bones
    rest = np.array(bones["upper_arm.L"].matrix_local)[:3, :3].T @ np.array(bones["forearm.L"].matrix_local)[:3, :3]
    parent = pose.matrices[pose.index["upper_arm.L"]][:3, :3]
    frame = _unit(parent.T).T @ rest  # the parent's axes normalised (columns), then the rest offset
    return frame.T @ _unit(pose.tail("forearm.L") - pose.head("forearm.L"))


def x_rotation(direction):
    return math.atan2(direction[2], direction[1])


def elbow_angle(obj, pose):
    a, b, c = (pose.head(n) for n in ("upper_arm.L", "forearm.L", "hand.L"))
    u, v = b - a, c - b
    return math.atan2(np.linalg.norm(np.cross(u, v)), float(u @ v))


def per_frame(obj, measure):
    out = []
    for frame in range(1, FRAMES + 1):
        bpy.context.scene.frame_set(frame)
        out.append(measure(obj, Pose(obj)))
    return np.array(out)


def basis_x_rotation(obj, pose):
    """The forearm's X rotation read from its keyed channels (before its constraints act)."""
    y = np.array(obj.pose.bones["forearm.L"].matrix_basis)[:3, 1]
    return x_rotation(y / np.linalg.norm(y))


def test_locked_forearm_keeps_its_elbow_angle_on_every_frame():
    free = rig_with_goals()
    start = elbow_angle(free, Pose(free))
    adjust_frames(free)
    bent = per_frame(free, elbow_angle)
    assert np.max(np.abs(bent - start)) > 0.3  # the goals make a free elbow bend

    locked = rig_with_goals()
    forearm = locked.pose.bones["forearm.L"]
    forearm.lock_ik_x = forearm.lock_ik_z = True
    adjust_frames(locked)
    angles = per_frame(locked, elbow_angle)
    assert np.max(np.abs(angles - start)) < ANGLE
    # Held, not swung about the upper arm: its direction in the upper arm's frame is its rest one.
    directions = per_frame(locked, forearm_in_rest_frame)
    np.testing.assert_allclose(directions, np.broadcast_to([0.0, 1.0, 0.0], directions.shape), atol=ANGLE)
    moved = per_frame(locked, lambda obj, pose: pose.head("hand.L"))
    assert np.ptp(moved, axis=0).max() > 0.05  # the arm still served the goals (the shoulder turned)


def test_ik_range_holds_on_every_frame():
    free = rig_with_goals()
    adjust_frames(free)
    wanted = per_frame(free, lambda obj, pose: x_rotation(forearm_in_rest_frame(obj, pose)))
    lo, hi = X_RANGE
    assert wanted.max() > hi + 0.5  # the goals pull far outside

    ranged = rig_with_goals()
    forearm = ranged.pose.bones["forearm.L"]
    forearm.use_ik_limit_x = True
    forearm.ik_min_x, forearm.ik_max_x = X_RANGE
    adjust_frames(ranged)
    x = per_frame(ranged, lambda obj, pose: x_rotation(forearm_in_rest_frame(obj, pose)))
    assert np.all(x >= lo - ANGLE) and np.all(x <= hi + ANGLE)
    assert x.max() > hi - 0.02 and np.ptp(x) > 0.05  # held at the bound, and bending inside the range


def test_local_limit_rotation_holds_on_the_keyed_channels():
    lo, hi = X_RANGE
    muted = rig_with_goals()
    con = muted.pose.bones["forearm.L"].constraints.new('LIMIT_ROTATION')
    con.owner_space, con.use_limit_x, con.min_x, con.max_x = 'LOCAL', True, lo, hi
    con.enabled = False
    adjust_frames(muted)
    wanted = per_frame(muted, basis_x_rotation)
    assert wanted.max() > hi + 0.5  # unread, the keys leave the range

    limited = rig_with_goals()
    con = limited.pose.bones["forearm.L"].constraints.new('LIMIT_ROTATION')
    con.owner_space, con.use_limit_x, con.min_x, con.max_x = 'LOCAL', True, lo, hi
    adjust_frames(limited)
    keyed = per_frame(limited, basis_x_rotation)
    assert np.all(keyed >= lo - ANGLE) and np.all(keyed <= hi + ANGLE)
    # The constraint had nothing left to clamp: the evaluated forearm is where its keys put it.
    evaluated = per_frame(limited, lambda obj, pose: x_rotation(forearm_in_rest_frame(obj, pose)))
    np.testing.assert_allclose(evaluated, keyed, atol=ANGLE)


def test_adjust_pose_honours_the_lock_too():
    obj = rig_with_goals()
    bpy.context.scene.frame_set(3)
    start = elbow_angle(obj, Pose(obj))
    forearm = obj.pose.bones["forearm.L"]
    forearm.lock_ik_x = forearm.lock_ik_z = True
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    assert abs(elbow_angle(obj, Pose(obj)) - start) < ANGLE


def test_settings_that_limit_no_direction_change_nothing():
    """Twist-only settings, muted or zero-influence LOCAL Limit Rotations, and joint limits switched off: keyed
    channels bit-identical to a rig that sets nothing."""
    plain = rig_with_goals()
    adjust_frames(plain)
    decorated = rig_with_goals()
    forearm = decorated.pose.bones["forearm.L"]
    forearm.lock_ik_y = True
    forearm.use_ik_limit_y, forearm.ik_min_y, forearm.ik_max_y = True, -0.1, 0.1
    for enabled, influence in ((False, 1.0), (True, 0.0)):
        con = forearm.constraints.new('LIMIT_ROTATION')
        con.owner_space, con.enabled, con.influence = 'LOCAL', enabled, influence
        con.use_limit_x, (con.min_x, con.max_x) = True, X_RANGE
    adjust_frames(decorated)
    for frame in range(1, FRAMES + 1):
        bpy.context.scene.frame_set(frame)
        assert pose_channels(decorated) == pose_channels(plain)

    off = rig_with_goals()
    off.fullbody_adjust.use_joint_limits = False
    adjust_frames(off)
    unlocked = rig_with_goals()
    unlocked.fullbody_adjust.use_joint_limits = False
    unlocked.pose.bones["forearm.L"].lock_ik_x = unlocked.pose.bones["forearm.L"].lock_ik_z = True
    adjust_frames(unlocked)
    for frame in range(1, FRAMES + 1):
        bpy.context.scene.frame_set(frame)
        assert pose_channels(unlocked) == pose_channels(off)


def test_bone_limits_reads_ik_settings_and_local_limit_rotations(extension_module_name):
    ik_limits = importlib.import_module(f"{extension_module_name}.bridge.reading.ik_limits")
    obj = add_rig("basic")
    pb = obj.pose.bones["shin.L"]
    assert not ik_limits.bone_limits(pb).limits_direction  # nothing set
    pb.lock_ik_z = True
    pb.use_ik_limit_x, pb.ik_min_x, pb.ik_max_x = True, -0.5, 0.6
    for name, space, influence, lo, hi in (("local", 'LOCAL', 1.0, -0.2, 1.0), ("world", 'WORLD', 1.0, 0.1, 0.2),
                                           ("off", 'LOCAL', 0.0, 0.3, 0.4)):
        con = pb.constraints.new('LIMIT_ROTATION')
        con.name, con.owner_space, con.influence = name, space, influence
        con.use_limit_x, con.min_x, con.max_x = True, lo, hi
        con.use_limit_y, con.min_y, con.max_y = True, -0.25, 0.25
    spec = ik_limits.bone_limits(pb)
    assert spec.locked == (False, False, True)
    lo, hi = spec.ranges[0]
    assert (lo, hi) == (pytest.approx(-0.2, abs=1e-7), pytest.approx(0.6, abs=1e-7))  # IK range and 'local' intersect
    assert spec.ranges[1] == (pytest.approx(-0.25, abs=1e-7), pytest.approx(0.25, abs=1e-7)) and spec.ranges[2] is None
    bones = obj.data.bones
    thigh, shin = (_unit(np.array(bones[n].matrix_local)[:3, :3].T).T for n in ("thigh.L", "shin.L"))  # unit columns
    np.testing.assert_allclose(spec.rest_in_parent, np.linalg.inv(thigh) @ shin, atol=1e-7)
    # Each source alone is read: one IK setting, or one constraint without any IK setting.
    for setting in ("lock_ik_x", "use_ik_limit_z"):
        other = obj.pose.bones["shin.R"]
        setattr(other, setting, True)
        assert ik_limits.bone_limits(other).limits_direction
        setattr(other, setting, False)
    con = obj.pose.bones["forearm.L"].constraints.new('LIMIT_ROTATION')
    con.owner_space, con.use_limit_z, con.min_z, con.max_z = 'LOCAL', True, -0.1, 0.1
    assert ik_limits.bone_limits(obj.pose.bones["forearm.L"]).ranges[2] == (
        pytest.approx(-0.1, abs=1e-7), pytest.approx(0.1, abs=1e-7))


def test_empty_constraint_range_is_one_clear_error():
    obj = rig_with_goals()
    con = obj.pose.bones["forearm.L"].constraints.new('LIMIT_ROTATION')
    con.owner_space, con.use_limit_x, con.min_x, con.max_x = 'LOCAL', True, 0.5, 0.1
    before = pose_channels(obj)
    with pytest.raises(RuntimeError, match="Limit Rotation 'Limit Rotation' has its minimum X above its maximum"):
        bpy.ops.fullbody_adjust.adjust_pose()
    assert pose_channels(obj) == before


def test_retargeting_keeps_the_target_rigs_range():
    """The source walk's elbows bend beyond the target metarig's forearm range: the retargeted keys stay in it."""
    from fullbody_adjust.bridge.retarget import run as retarget

    from .test_retarget import add_metarig, import_clip

    source = import_clip()
    free, limited = add_metarig(location=(1.5, 0.0, 0.0)), add_metarig(location=(-1.5, 0.0, 0.0))
    forearm = limited.pose.bones["forearm.L"]
    forearm.use_ik_limit_x = True
    forearm.ik_min_x, forearm.ik_max_x = X_RANGE
    lo, hi = X_RANGE
    frames = range(2, 41)

    def x_rotations(obj):
        out = []
        for frame in frames:
            bpy.context.scene.frame_set(frame)
            out.append(x_rotation(forearm_in_rest_frame(obj, Pose(obj))))
        return np.array(out)

    retarget.retarget(bpy.context, source, free, frames[0], frames[-1])
    wanted = x_rotations(free)
    assert wanted.min() < lo - 0.1 or wanted.max() > hi + 0.1  # the walk's elbow leaves the range
    retarget.retarget(bpy.context, source, limited, frames[0], frames[-1])
    x = x_rotations(limited)
    assert np.all(x >= lo - ANGLE) and np.all(x <= hi + ANGLE)
