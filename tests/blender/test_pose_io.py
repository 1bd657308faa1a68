"""Pose in (world space), rotations out (bridge/reading/pose.py, bridge/writing/channels.py), through
the bpy wheel.

Each test asks for new world matrices, converts and applies them, lets Blender evaluate the pose and
reads the result back: the bones land where asked, bones outside the request keep their local channels
and follow their parents, twist is kept, and rotations stay continuous in every rotation mode.
"""

import math
from types import SimpleNamespace

import bpy
import numpy as np
import pytest
from mathutils import Euler, Matrix, Quaternion

from fullbody_adjust.bridge.writing import channels as channels_module
from fullbody_adjust.bridge.errors import AdjustError
from fullbody_adjust.bridge.writing.keyframes import key_bones_frames
from fullbody_adjust.solver.vocabulary import EULER_ORDERS
from fullbody_adjust.bridge.reading.pose import as_batch, evaluated_heads, read_pose, read_pose_frames, rotation_modes
from fullbody_adjust.bridge.writing.channels import apply_channels

from .scene_tools import key_bones, swing_world_matrices, world_rotations_to_channels
from .test_keyframes import fcurves_of

ROTATION_MODES = ("QUATERNION",) + EULER_ORDERS + ("AXIS_ANGLE",)

# name, parent, connected, head (None: the parent's tail), tail, roll, rotation mode, inherit rotation.
# Connected and unconnected bones, a bone that does not inherit its parent's rotation ("hand"), a bone
# outside the groups between two group bones ("hip", between "root" and "leg"), and every rotation mode.
CHAIN_RIG = (
    ("root", None, False, (0.0, 0.0, 1.0), (0.0, 0.05, 1.2), 0.3, "QUATERNION", True),
    ("spine", "root", True, None, (0.02, 0.0, 1.5), -0.4, "XYZ", True),
    ("chest", "spine", True, None, (0.0, -0.03, 1.8), 0.7, "XZY", True),
    ("arm", "chest", False, (0.2, 0.0, 1.7), (0.5, 0.05, 1.6), 1.1, "YXZ", True),
    ("forearm", "arm", True, None, (0.8, 0.1, 1.55), -0.6, "YZX", True),
    ("hand", "forearm", True, None, (0.95, 0.12, 1.5), 0.2, "ZXY", False),
    ("finger", "hand", True, None, (1.02, 0.13, 1.48), 0.5, "ZYX", True),
    ("hip", "root", False, (0.1, 0.0, 0.95), (0.12, 0.02, 0.9), 0.0, "QUATERNION", True),
    ("leg", "hip", True, None, (0.13, -0.05, 0.5), 0.9, "AXIS_ANGLE", True),
    ("shin", "leg", True, None, (0.14, 0.03, 0.08), -1.2, "QUATERNION", True),
    ("side", "root", False, (-0.15, 0.05, 1.1), (-0.2, 0.1, 1.3), 0.0, "XYZ", True),
)
CHAIN_GROUPS = ("root", "spine", "chest", "arm", "forearm", "hand", "leg", "shin")

# location, Euler XYZ rotation, scale of the armature object.
OBJECT_TRANSFORMS = {
    "identity": ((0, 0, 0), (0, 0, 0), (1, 1, 1)),
    "moved_rotated": ((1.0, -2.0, 0.5), (0.3, -0.5, 1.2), (1, 1, 1)),
    "uniform_scale": ((1.0, -2.0, 0.5), (0.3, -0.5, 1.2), (2.5, 2.5, 2.5)),
    "nonuniform_scale": ((1.0, -2.0, 0.5), (0.3, -0.5, 1.2), (1.0, 2.0, 0.5)),
}
UNIFORM = ("identity", "moved_rotated", "uniform_scale")

RIGIFY_GROUPS = ("spine", "spine.001", "spine.002", "spine.003", "shoulder.L", "upper_arm.L", "forearm.L",
                 "hand.L", "shoulder.R", "upper_arm.R", "forearm.R", "hand.R", "thigh.L", "shin.L", "foot.L",
                 "thigh.R", "shin.R", "foot.R")


# --- rigs -----------------------------------------------------------------------------------------------


def make_armature(name="Rig"):
    armature = bpy.data.armatures.new(name)
    obj = bpy.data.objects.new(name, armature)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    return obj


def build_chain_rig(transform="identity", seed=0):
    """The hand-made chain rig, posed away from rest with random channels, its object transformed."""
    obj = make_armature()
    bpy.ops.object.mode_set(mode='EDIT')
    edit_bones = obj.data.edit_bones
    for name, parent, connected, head, tail, roll, _mode, inherit in CHAIN_RIG:
        bone = edit_bones.new(name)
        bone.head = head if head is not None else edit_bones[parent].tail
        bone.tail = tail
        bone.roll = roll
        if parent:
            bone.parent = edit_bones[parent]
            bone.use_connect = connected
        bone.use_inherit_rotation = inherit
    bpy.ops.object.mode_set(mode='OBJECT')
    rng = np.random.default_rng(seed)
    for name, _parent, connected, _head, _tail, _roll, mode, _inherit in CHAIN_RIG:
        pose_bone = obj.pose.bones[name]
        pose_bone.rotation_mode = mode
        set_rotation(pose_bone, random_rotation(rng, 0.6))
        if not connected:
            pose_bone.location = rng.uniform(-0.05, 0.05, 3)
    obj.pose.bones["chest"].scale = (1.1, 1.1, 1.1)  # inherited by the arm: scale must be kept
    obj.pose.bones["side"].scale = (0.9, 1.2, 0.9)
    set_object_transform(obj, transform)
    return obj


def rigify_metarig(transform="identity"):
    if "rigify" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="rigify")
    bpy.ops.object.armature_basic_human_metarig_add()
    obj = bpy.context.object
    set_object_transform(obj, transform)
    return obj


def set_object_transform(obj, transform):
    location, rotation, scale = OBJECT_TRANSFORMS[transform]
    obj.location, obj.rotation_euler, obj.scale = location, rotation, scale
    bpy.context.view_layer.update()


def set_rotation(pose_bone, matrix3):
    """Set a pose bone's rotation from a 3x3 rotation in whatever its rotation mode is."""
    rotation = Matrix(matrix3)
    mode = pose_bone.rotation_mode
    if mode == "QUATERNION":
        pose_bone.rotation_quaternion = rotation.to_quaternion()
    elif mode == "AXIS_ANGLE":
        axis, angle = rotation.to_quaternion().to_axis_angle()
        pose_bone.rotation_axis_angle = (angle, *axis)
    else:
        pose_bone.rotation_euler = rotation.to_euler(mode)


# --- numbers --------------------------------------------------------------------------------------------


def axis_rotation(axis, angle):
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def random_rotation(rng, max_angle):
    return axis_rotation(rng.normal(size=3), rng.uniform(0.2, 1.0) * max_angle)


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def world_matrices(obj):
    """Blender's own evaluated world matrices of every pose bone (B,4,4), after a depsgraph update."""
    bpy.context.view_layer.update()
    world = np.array(obj.matrix_world)
    return np.array([world @ np.array(pb.matrix) for pb in obj.pose.bones])


def local_channels(obj, name):
    pb = obj.pose.bones[name]
    return (tuple(pb.location), tuple(pb.rotation_quaternion), tuple(pb.rotation_euler),
            tuple(pb.rotation_axis_angle), tuple(pb.scale), pb.rotation_mode)


def realizable_request(snapshot, group, rng, head_offsets=None, max_angle=0.8):
    """New world matrices for `group`: each bone turned by a random rotation (in armature space), its head
    carried rigidly by its parent (plus optional armature-space head offsets). Also returns the world
    matrices every bone must end up with: bones outside the group keep their local transform and are
    carried by their parents. Reachable under any object scale."""
    head_offsets = head_offsets or {}
    pose = snapshot.pose_matrices
    new = pose.copy()
    for i, name in enumerate(snapshot.names):
        p = snapshot.parents[i]
        carry = new[p] @ np.linalg.inv(pose[p]) if p >= 0 else np.eye(4)
        new[i] = carry @ pose[i]
        if name in group:
            new[i][:3, :3] = random_rotation(rng, max_angle) @ pose[i][:3, :3]
            new[i][:3, 3] += head_offsets.get(name, 0.0)
    world = snapshot.matrix_world @ new
    return world[snapshot.indices(group)], world


def assert_world_close(actual, expected, snapshot, atol=1e-5):
    # float32 in Blender: allow for the size of the coordinates.
    size = max(1.0, float(np.abs(snapshot.matrices[..., :3, 3]).max()))
    np.testing.assert_allclose(actual, expected, rtol=0, atol=atol * size)


# --- reading --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("transform", sorted(OBJECT_TRANSFORMS))
def test_read_pose_matches_blender(transform):
    obj = build_chain_rig(transform)
    snapshot = read_pose(obj)
    world = np.array(obj.matrix_world)
    assert snapshot.names == tuple(b.name for b in obj.data.bones)
    assert [snapshot.names[p] if p >= 0 else None for p in snapshot.parents] == \
        [b.parent.name if b.parent else None for b in obj.data.bones]
    assert snapshot.use_connect.tolist() == [b.use_connect for b in obj.data.bones]
    assert snapshot.rotation_modes == tuple(pb.rotation_mode for pb in obj.pose.bones)
    np.testing.assert_allclose(snapshot.matrix_world, world, atol=1e-6)
    for i, pb in enumerate(obj.pose.bones):
        head = world @ np.append(np.array(pb.head), 1.0)
        tail = world @ np.append(np.array(pb.tail), 1.0)
        np.testing.assert_allclose(snapshot.matrices[i], world @ np.array(pb.matrix), atol=1e-6)
        np.testing.assert_allclose(snapshot.pose_matrices[i], np.array(pb.matrix), atol=1e-7)
        np.testing.assert_allclose(snapshot.rest_matrices[i], np.array(pb.bone.matrix_local), atol=1e-7)
        np.testing.assert_allclose(snapshot.heads[i], head[:3], atol=1e-6)
        np.testing.assert_allclose(snapshot.tails[i], tail[:3], atol=1e-6)
        assert snapshot.lengths[i] == pytest.approx(np.linalg.norm(tail - head), abs=1e-6)
        np.testing.assert_array_equal(snapshot.channels["location"][i], np.array(pb.location, np.float32))
        np.testing.assert_array_equal(snapshot.channels["rotation_euler"][i],
                                      np.array(pb.rotation_euler, np.float32))
    # A few bones' heads alone read the same, bit for bit.
    picked = [3, 0, len(snapshot.names) - 1]
    np.testing.assert_array_equal(evaluated_heads(obj, [snapshot.names[i] for i in picked]), snapshot.heads[picked])
    # The world matrix's translation is the head; its Y axis points along the bone.
    np.testing.assert_allclose(snapshot.matrices[:, :3, 3], snapshot.heads, atol=1e-6)
    y = unit(snapshot.matrices[:, :3, 1])
    np.testing.assert_allclose(y, unit(snapshot.tails - snapshot.heads), atol=1e-6)


def test_rotation_modes_read_in_bulk_name_every_mode():
    obj = build_chain_rig("identity")
    modes = [item.identifier for item in bpy.types.PoseBone.bl_rna.properties["rotation_mode"].enum_items]
    assert len(modes) == 8
    for shift in range(len(modes)):
        for i, pb in enumerate(obj.pose.bones):
            pb.rotation_mode = modes[(i + shift) % len(modes)]
        assert rotation_modes(obj) == tuple(pb.rotation_mode for pb in obj.pose.bones)


def test_read_pose_frames_matches_read_pose_at_each_frame():
    obj = build_chain_rig("moved_rotated")
    scene = bpy.context.scene
    for frame, angle, x in ((1, 0.0, 1.0), (11, 1.2, 3.0)):
        obj.pose.bones["spine"].rotation_euler = (angle, 0.1, 0.0)
        obj.pose.bones["spine"].keyframe_insert("rotation_euler", frame=frame)
        obj.location.x = x
        obj.keyframe_insert("location", frame=frame)
    scene.frame_set(4)
    frames = [1, 5.5, 11]
    batch = read_pose_frames(obj, frames)
    assert (scene.frame_current, scene.frame_subframe) == (4, 0.0)
    assert batch.batched and batch.matrices.shape == (3, len(CHAIN_RIG), 4, 4)
    np.testing.assert_array_equal(batch.frame, frames)
    for row, frame in enumerate(frames):
        scene.frame_set(int(frame), subframe=frame - int(frame))
        single = read_pose(obj)
        for field in ("matrix_world", "pose_matrices", "matrices", "heads", "tails", "lengths"):
            np.testing.assert_array_equal(getattr(batch, field)[row], getattr(single, field))
        np.testing.assert_array_equal(batch.channels["rotation_euler"][row], single.channels["rotation_euler"])
    # The animation really moved things between the frames read.
    assert not np.allclose(batch.matrices[0], batch.matrices[2], atol=1e-3)


def test_read_pose_rejects_non_armatures():
    empty = bpy.data.objects.new("Empty", None)
    with pytest.raises(AdjustError, match="not an armature"):
        read_pose(empty)


# --- writing: world matrices land where asked -------------------------------------------------------------


def test_one_frames_reachable_matrices_are_the_batch_paths_bit_for_bit():
    """The one-frame conversion reduces requested matrices to what rigid bones can do in plain floats: the same
    bits as the numpy path gives for that frame among others, scaled and sheared input included."""
    rng = np.random.default_rng(7)
    k, frames = 6, 5
    requested = rng.normal(size=(frames, k, 4, 4))
    requested[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    pose_matrices = rng.normal(size=(frames, 9, 4, 4))
    idx = np.array([1, 2, 4, 5, 7, 8])
    batch = channels_module._reachable_armature_matrices(SimpleNamespace(pose_matrices=pose_matrices), requested, idx)
    for f in range(frames):
        one = channels_module._reachable_armature_matrices(SimpleNamespace(pose_matrices=pose_matrices[f:f + 1]),
                                                       requested[f:f + 1], idx)
        assert one.shape == (1, k, 4, 4)
        assert one.tobytes() == batch[f:f + 1].tobytes()
    with pytest.raises(ValueError, match="Y axis"):
        flat = requested[:1].copy()
        flat[0, 2, :3, 1] = 0.0
        channels_module._reachable_armature_matrices(SimpleNamespace(pose_matrices=pose_matrices[:1]), flat, idx)


def test_what_a_snapshot_keeps_is_its_own():
    """A snapshot's batch form and derived values are made once and kept with it; a value that depends on
    another object is made again for another one; a copy of the snapshot keeps nothing of them."""
    obj = build_chain_rig()
    snapshot = read_pose(obj)
    assert as_batch(snapshot) is as_batch(snapshot)
    np.testing.assert_array_equal(as_batch(snapshot).heads[0], snapshot.heads)
    made = []

    def make():
        made.append(len(made))
        return len(made)

    first, second = object(), object()
    assert snapshot.derived("count", make, of=first) == 1
    assert snapshot.derived("count", make, of=first) == 1
    assert snapshot.derived("count", make, of=second) == 2
    assert read_pose(obj).derived("count", make, of=second) == 3  # another snapshot of the same pose
    assert as_batch(snapshot).derived("count", make, of=second) == 4


@pytest.mark.parametrize("transform", sorted(OBJECT_TRANSFORMS))
def test_requested_world_matrices_are_reproduced(transform):
    obj = build_chain_rig(transform, seed=1)
    snapshot = read_pose(obj)
    others = [n for n in snapshot.names if n not in CHAIN_GROUPS]
    before = {name: local_channels(obj, name) for name in snapshot.names}
    rng = np.random.default_rng(2)
    # The pelvis translates and the unconnected "arm" is pulled off its parent: both get a location.
    requested, expected = realizable_request(
        snapshot, CHAIN_GROUPS, rng, head_offsets={"root": np.array([0.1, -0.2, 0.05]),
                                                   "arm": np.array([0.0, 0.03, -0.02])})

    channels = world_rotations_to_channels(obj, snapshot, requested, CHAIN_GROUPS)
    apply_channels(obj, channels)

    assert_world_close(world_matrices(obj), expected, snapshot)
    # Only unconnected bones whose head moved get a location; nothing writes scale.
    assert {n for n, props in channels.items() if "location" in props} == {"root", "arm"}
    for name in CHAIN_GROUPS:
        after = local_channels(obj, name)
        assert after[4] == before[name][4], f"{name}: scale changed"
        if name not in ("root", "arm"):
            assert after[0] == before[name][0], f"{name}: location changed"
    for name in others:
        assert local_channels(obj, name) == before[name], f"{name} is outside the groups but changed"


@pytest.mark.parametrize("transform", ["moved_rotated", "uniform_scale"])
def test_rigify_metarig_pelvis_moves_and_limbs_turn(transform):
    obj = rigify_metarig(transform)
    snapshot = read_pose(obj)
    before = {name: local_channels(obj, name) for name in snapshot.names}
    requested, expected = realizable_request(snapshot, RIGIFY_GROUPS, np.random.default_rng(3),
                                             head_offsets={"spine": np.array([0.05, -0.1, -0.15])})

    channels = world_rotations_to_channels(obj, snapshot, requested, RIGIFY_GROUPS)
    apply_channels(obj, channels)

    assert_world_close(world_matrices(obj), expected, snapshot)
    # The root bone gets the pelvis move; shoulder->upper_arm is unconnected but the arm's head did not
    # move relative to the shoulder, so no other bone gets a location.
    assert {n for n, props in channels.items() if "location" in props} == {"spine"}
    for name in snapshot.names:
        if name not in RIGIFY_GROUPS:
            assert local_channels(obj, name) == before[name], f"{name} is outside the groups but changed"
        elif name != "spine":
            assert local_channels(obj, name)[0] == before[name][0]


def test_unmoved_pelvis_gets_no_location():
    obj = build_chain_rig("moved_rotated", seed=4)
    snapshot = read_pose(obj)
    before = {name: local_channels(obj, name) for name in snapshot.names}
    requested, expected = realizable_request(snapshot, CHAIN_GROUPS, np.random.default_rng(5))
    channels = world_rotations_to_channels(obj, snapshot, requested, CHAIN_GROUPS)
    apply_channels(obj, channels)
    assert_world_close(world_matrices(obj), expected, snapshot)
    assert not any("location" in props for props in channels.values())
    assert all(local_channels(obj, name)[0] == before[name][0] for name in snapshot.names)


def test_bone_not_inheriting_rotation_keeps_world_rotation_when_parent_turns():
    obj = build_chain_rig("moved_rotated", seed=6)
    snapshot = read_pose(obj)
    hand = snapshot.index("hand")
    before = local_channels(obj, "hand")
    # Turn the forearm only; the hand (use_inherit_rotation off) is not listed: it keeps its local channels,
    # so its world rotation stays while its head follows the forearm's tail.
    requested, expected = realizable_request(snapshot, ("forearm",), np.random.default_rng(7))
    apply_channels(obj, world_rotations_to_channels(obj, snapshot, requested, ["forearm"]))
    after = world_matrices(obj)
    assert local_channels(obj, "hand") == before
    np.testing.assert_allclose(after[hand][:3, :3], snapshot.matrices[hand][:3, :3], atol=1e-5)
    forearm_tail = np.array(obj.matrix_world @ obj.pose.bones["forearm"].tail)
    np.testing.assert_allclose(after[hand][:3, 3], forearm_tail, atol=1e-5)
    assert_world_close(after[snapshot.index("forearm")], requested[0], snapshot)
    # The forearm really turned, so keeping the hand's world rotation was not trivial.
    assert not np.allclose(after[snapshot.index("forearm")], snapshot.matrices[snapshot.index("forearm")],
                           atol=1e-3)


def test_nonuniform_scale_keeps_head_and_direction_of_unreachable_request():
    """Under non-uniform object scale a world-space turn of a matrix is not a rigid bone motion: the bone
    takes the requested head and direction, and keeps its length in armature space."""
    obj = build_chain_rig("nonuniform_scale", seed=8)
    snapshot = read_pose(obj)
    rng = np.random.default_rng(9)
    names = ["root", "arm"]
    idx = snapshot.indices(names)
    requested = snapshot.matrices[idx].copy()
    for row in requested:
        row[:3, :3] = random_rotation(rng, 1.0) @ row[:3, :3]  # world-space turn: shears in armature space
        row[:3, 3] += rng.uniform(-0.1, 0.1, 3)
    apply_channels(obj, world_rotations_to_channels(obj, snapshot, requested, names))
    after = world_matrices(obj)
    np.testing.assert_allclose(after[idx, :3, 3], requested[:, :3, 3], atol=1e-5)
    np.testing.assert_allclose(unit(after[idx, :3, 1]), unit(requested[:, :3, 1]), atol=1e-5)
    for i in idx:
        pb = obj.pose.bones[snapshot.names[i]]
        assert (pb.tail - pb.head).length == pytest.approx(np.linalg.norm(
            np.linalg.inv(snapshot.matrix_world)[:3, :3] @ (snapshot.tails[i] - snapshot.heads[i])), abs=1e-6)


# --- twist ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("transform", sorted(OBJECT_TRANSFORMS))
def test_swing_keeps_twist(transform):
    """swing_world_matrices + conversion: each bone's Y axis points along its new direction, and the turn
    from its old rotation is the minimal swing (axis along old x new, angle between them): no twist.
    Checked in world space under uniform scale, in armature space (the rig's own) under non-uniform."""
    obj = build_chain_rig(transform, seed=10)
    snapshot = read_pose(obj)
    rng = np.random.default_rng(11)
    chain = ["root", "spine", "chest", "arm", "forearm", "hand"]
    new_world = {}
    for name in chain:  # top-down: a bone's head rides on its parent's new matrix
        i = snapshot.index(name)
        p = snapshot.parents[i]
        head = snapshot.heads[i]
        if snapshot.names[p] in new_world:
            carry = new_world[snapshot.names[p]] @ np.linalg.inv(snapshot.matrices[p])
            head = (carry @ np.append(head, 1.0))[:3]
        old_dir = snapshot.tails[i] - snapshot.heads[i]
        new_dir = random_rotation(rng, 1.2) @ old_dir
        new_world[name] = swing_world_matrices(snapshot, [name], [old_dir], [new_dir], [head])[0]
        new_world[name + ".dirs"] = (old_dir, new_dir)
    requested = np.array([new_world[name] for name in chain])
    apply_channels(obj, world_rotations_to_channels(obj, snapshot, requested, chain))
    after = world_matrices(obj)

    assert_world_close(after[snapshot.indices(chain)], requested, snapshot)
    to_armature = np.linalg.inv(snapshot.matrix_world)
    for name in chain:
        i = snapshot.index(name)
        old_dir, new_dir = new_world[name + ".dirs"]
        old, new = snapshot.matrices[i], after[i]
        if transform not in UNIFORM:
            old, new = to_armature @ old, to_armature @ new
            old_dir, new_dir = to_armature[:3, :3] @ old_dir, to_armature[:3, :3] @ new_dir
        np.testing.assert_allclose(unit(new[:3, 1]), unit(new_dir), atol=1e-5)
        turn = unit_columns(new[:3, :3]) @ unit_columns(old[:3, :3]).T
        skew = 0.5 * np.array([turn[2, 1] - turn[1, 2], turn[0, 2] - turn[2, 0], turn[1, 0] - turn[0, 1]])
        np.testing.assert_allclose(skew, np.cross(unit(old_dir), unit(new_dir)), atol=1e-5)
        assert np.trace(turn) == pytest.approx(1 + 2 * np.dot(unit(old_dir), unit(new_dir)), abs=1e-5)
        if transform in UNIFORM:  # bone lengths never change
            assert np.linalg.norm(new[:3, 1]) == pytest.approx(np.linalg.norm(old[:3, 1]), rel=1e-6)


def unit_columns(m):
    return m / np.linalg.norm(m, axis=0, keepdims=True)


# --- continuity -------------------------------------------------------------------------------------------


def spin_rig(mode):
    """One root bone 'spin' in `mode` on a moved, rotated, scaled object."""
    obj = make_armature()
    bpy.ops.object.mode_set(mode='EDIT')
    bone = obj.data.edit_bones.new("spin")
    bone.head, bone.tail, bone.roll = (0.1, 0.2, 0.3), (0.3, 0.5, 1.0), 0.4
    bpy.ops.object.mode_set(mode='OBJECT')
    obj.pose.bones["spin"].rotation_mode = mode
    set_object_transform(obj, "uniform_scale")
    return obj


def spin_request(obj, frames, mode):
    """World matrices of 'spin' over frames: its local rotation winds more than two full turns about the
    first axis of its Euler order (so Euler angles stay clear of gimbal lock) with a wobble on the others."""
    order = mode if mode in EULER_ORDERS else "XYZ"
    first = "XYZ".index(order[0])
    rest = np.array(obj.data.bones["spin"].matrix_local)
    world = np.array(obj.matrix_world)
    out = []
    for f in frames:
        angles = [0.3 * math.sin(0.4 * f), 0.25 * math.cos(0.3 * f), 0.2 * math.sin(0.5 * f)]
        angles[first] = 0.5 * f
        local = np.array(Euler(angles, order).to_matrix().to_4x4())
        out.append(world @ rest @ local)
    return np.array(out)


def rotation_keys(obj, prop, size):
    curves = fcurves_of(obj)
    data_path = f'pose.bones["spin"].{prop}'
    return np.stack([curves[(data_path, i)]["co"][:, 1] for i in range(size)], axis=1)


def assert_continuous(prop, keys):
    steps = np.diff(keys, axis=0)
    if prop == "rotation_quaternion":
        assert np.all(np.sum(keys[1:] * keys[:-1], axis=1) > 0), "quaternion sign flip between keys"
    elif prop == "rotation_euler":
        assert np.all(np.abs(steps) < math.pi), "Euler jump between keys"
    else:
        assert np.all(np.sum(keys[1:, 1:] * keys[:-1, 1:], axis=1) > 0), "axis-angle axis flip between keys"
        assert np.all(np.abs(steps[:, 0]) < math.pi), "axis-angle angle jump between keys"


PROPERTY = {"QUATERNION": ("rotation_quaternion", 4), "AXIS_ANGLE": ("rotation_axis_angle", 4)}


@pytest.mark.parametrize("batched", [False, True], ids=["per_frame", "batched"])
@pytest.mark.parametrize("mode", ROTATION_MODES)
def test_keys_of_a_winding_bone_stay_continuous(mode, batched):
    obj = spin_rig(mode)
    scene = bpy.context.scene
    frames = list(range(1, 31))
    requested = spin_request(obj, frames, mode)
    prop, size = PROPERTY.get(mode, ("rotation_euler", 3))
    if batched:
        snapshot = read_pose_frames(obj, frames)
        channels = world_rotations_to_channels(obj, snapshot, requested[:, None], ["spin"])
        key_bones_frames(obj, ["spin"], frames, channels)
    else:
        for f, matrix in zip(frames, requested):
            scene.frame_set(f)
            snapshot = read_pose(obj)
            channels = world_rotations_to_channels(obj, snapshot, matrix[None], ["spin"])
            apply_channels(obj, channels)
            key_bones(obj, ["spin"], f, channels=("rotation",))
    keys = rotation_keys(obj, prop, size)
    assert len(keys) == len(frames)
    assert_continuous(prop, keys)
    if mode == "AXIS_ANGLE":  # the angle really wound past a full turn, continuously
        assert np.ptp(keys[:, 0]) > 2 * math.pi
    for f, matrix in zip(frames, requested):
        scene.frame_set(f)
        assert_world_close(world_matrices(obj)[0], matrix, snapshot)


def test_apply_channels_keeps_each_mode_continuous_with_the_current_value():
    obj = build_chain_rig()
    root, spine, leg = (obj.pose.bones[n] for n in ("root", "spine", "leg"))
    root.rotation_quaternion = Quaternion((0.8, 0.1, -0.5, 0.3)).normalized()
    spine.rotation_euler = (3.0, 0.2, -3.0)
    leg.rotation_axis_angle = (5.0, 0.0, 0.6, 0.8)
    q = -np.array(root.rotation_quaternion)  # the same rotation, other hemisphere
    euler = np.array(spine.rotation_euler) + (0.1 - 2 * math.pi, 0.0, 2 * math.pi - 0.1)
    axis_angle = np.array((-(5.0 - 2 * math.pi) - 0.1, 0.0, -0.6, -0.8))  # (-a, -n) == (a, n)
    apply_channels(obj, {"root": {"rotation_quaternion": q}, "spine": {"rotation_euler": euler},
                         "leg": {"rotation_axis_angle": axis_angle}})
    np.testing.assert_allclose(root.rotation_quaternion, -q, atol=1e-7)
    np.testing.assert_allclose(spine.rotation_euler, (3.1, 0.2, -3.1), atol=1e-5)
    np.testing.assert_allclose(leg.rotation_axis_angle, (5.1, 0.0, 0.6, 0.8), atol=1e-5)


def test_bad_input_is_rejected_before_anything_changes():
    obj = build_chain_rig()
    snapshot = read_pose(obj)
    before = {name: local_channels(obj, name) for name in snapshot.names}
    with pytest.raises(ValueError, match="shape"):
        world_rotations_to_channels(obj, snapshot, np.zeros((1, 4, 4)), ["root", "spine"])
    with pytest.raises(ValueError, match="NaN"):
        world_rotations_to_channels(obj, snapshot, np.full((1, 4, 4), np.nan), ["root"])
    with pytest.raises(AdjustError, match="no bone named 'nope'"):
        world_rotations_to_channels(obj, snapshot, np.zeros((1, 4, 4)), ["nope"])
    with pytest.raises(ValueError, match="rotates in mode XYZ"):
        apply_channels(obj, {"spine": {"rotation_quaternion": (1, 0, 0, 0)}})
    assert {name: local_channels(obj, name) for name in snapshot.names} == before
