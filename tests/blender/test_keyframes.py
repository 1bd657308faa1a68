"""Keyframes for pose bones (bridge/writing/keyframes.py), through the bpy wheel: the same tests pass on 4.2
(legacy F-Curves), 4.5 (slots) and 5.x (channelbags)."""

import bpy
import numpy as np
import pytest

from fullbody_adjust.bridge.errors import AdjustError
from fullbody_adjust.bridge.writing.keyframes import key_bones_frames
from fullbody_adjust.bridge.reading.pose import read_pose
from fullbody_adjust.bridge.writing.channels import apply_channels

from .scene_tools import key_bones, world_rotations_to_channels

# name, rotation mode: one bone per kind of rotation property.
BONES = (("a", "QUATERNION"), ("b", "XYZ"), ("c", "AXIS_ANGLE"))


def animating_fcurves(obj, action=None):
    """The F-Curves animating obj in `action` (default: its assigned action), found the way each Blender
    version stores them."""
    anim = obj.animation_data
    action = action or anim.action
    if not hasattr(action, "layers"):
        return list(action.fcurves)
    slot = anim.action_slot if action == anim.action else action.slots[0]
    return [fc for layer in action.layers for strip in layer.strips
            for bag in strip.channelbags if bag.slot == slot for fc in bag.fcurves]


def fcurves_of(obj, action=None):
    """{(data_path, index): {'co', 'left', 'right', 'interpolation', 'group'}} of animating_fcurves."""
    curves = animating_fcurves(obj, action)
    out = {}
    for fc in curves:
        points = fc.keyframe_points
        n = len(points)
        co, left, right = (np.empty(2 * n, np.float32) for _ in range(3))
        interpolation = np.empty(n, np.int32)
        points.foreach_get("co", co)
        points.foreach_get("handle_left", left)
        points.foreach_get("handle_right", right)
        points.foreach_get("interpolation", interpolation)
        out[(fc.data_path, fc.array_index)] = {
            "co": co.reshape(n, 2), "left": left.reshape(n, 2), "right": right.reshape(n, 2),
            "interpolation": interpolation, "group": fc.group.name if fc.group else None}
    return out


def assert_same_curve(after, before):
    for key in ("co", "left", "right", "interpolation"):
        np.testing.assert_array_equal(after[key], before[key])
    assert after["group"] == before["group"]


def path(bone, prop):
    return f'pose.bones["{bone}"].{prop}'


@pytest.fixture
def rig():
    armature = bpy.data.armatures.new("Rig")
    obj = bpy.data.objects.new("Rig", armature)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    for i, (name, _mode) in enumerate(BONES):
        bone = armature.edit_bones.new(name)
        bone.head, bone.tail = (i, 0, 0), (i, 0, 1)
    bpy.ops.object.mode_set(mode='OBJECT')
    for name, mode in BONES:
        obj.pose.bones[name].rotation_mode = mode
    return obj


def set_pose(obj, seed):
    """Give every bone a distinct location and rotation."""
    rng = np.random.default_rng(seed)
    for name, _mode in BONES:
        pb = obj.pose.bones[name]
        pb.location = rng.uniform(-1, 1, 3)
        pb.rotation_quaternion = rng.uniform(-1, 1, 4)
        pb.rotation_euler = rng.uniform(-3, 3, 3)
        pb.rotation_axis_angle = rng.uniform(-1, 1, 4)


def pose_values(obj):
    return {pb.name: (tuple(pb.location), tuple(pb.rotation_quaternion), tuple(pb.rotation_euler),
                      tuple(pb.rotation_axis_angle)) for pb in obj.pose.bones}


def keyed_rig(obj, frames=(1, 10, 20), interpolation="BEZIER"):
    """Keys on every bone's location and rotation at `frames`, inserted by Blender itself."""
    rotation = {"QUATERNION": "rotation_quaternion", "XYZ": "rotation_euler", "AXIS_ANGLE": "rotation_axis_angle"}
    for seed, frame in enumerate(frames):
        set_pose(obj, seed)
        for name, mode in BONES:
            pb = obj.pose.bones[name]
            pb.keyframe_insert("location", frame=frame, group=name)
            pb.keyframe_insert(rotation[mode], frame=frame, group=name)
    for fc in animating_fcurves(obj):
        for point in fc.keyframe_points:
            point.interpolation = interpolation
    return fcurves_of(obj)


def evaluated_values(obj, frame, bone, prop):
    scene = bpy.context.scene
    scene.frame_set(frame + 1)
    scene.frame_set(frame)
    return np.array(getattr(obj.pose.bones[bone], prop))


def test_key_bones_creates_the_action_and_keys_only_those_bones(rig):
    set_pose(rig, 0)
    expected = pose_values(rig)
    action = key_bones(rig, ["a", "b"], 7)

    assert rig.animation_data.action == action
    if hasattr(rig.animation_data, "action_slot"):  # 4.4+: without a slot the action animates nothing
        assert rig.animation_data.action_slot is not None
    curves = fcurves_of(rig)
    assert set(curves) == ({(path("a", "location"), i) for i in range(3)}
                           | {(path("a", "rotation_quaternion"), i) for i in range(4)}
                           | {(path("b", "location"), i) for i in range(3)}
                           | {(path("b", "rotation_euler"), i) for i in range(3)})
    for (data_path, index), curve in curves.items():
        bone = data_path.split('"')[1]
        assert curve["group"] == bone
        prop = data_path.rsplit(".", 1)[1]
        value = expected[bone][("location", "rotation_quaternion", "rotation_euler").index(prop)][index]
        np.testing.assert_array_equal(curve["co"], np.array([[7, value]], np.float32))
    # The keys animate the bones: move them away, change frame and come back.
    set_pose(rig, 1)
    np.testing.assert_allclose(evaluated_values(rig, 7, "a", "rotation_quaternion"), expected["a"][1], atol=1e-6)
    np.testing.assert_allclose(evaluated_values(rig, 7, "b", "location"), expected["b"][0], atol=1e-6)


def test_keys_on_other_frames_and_bones_are_kept_and_same_frame_replaced(rig):
    keyed_rig(rig, interpolation="LINEAR")
    # A hand-shaped key (free handles) at the frame that gets replaced: its shape moves with its value.
    shaped = next(fc for fc in animating_fcurves(rig)
                  if (fc.data_path, fc.array_index) == (path("a", "location"), 0))
    point = shaped.keyframe_points[1]
    point.handle_left_type = point.handle_right_type = "FREE"
    point.handle_left = (point.co.x - 2.0, point.co.y + 0.7)
    point.handle_right = (point.co.x + 3.0, point.co.y - 0.4)
    before = fcurves_of(rig)
    values = {"a": {"location": np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]),
                    "rotation_quaternion": np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])},
              "b": {"rotation_euler": np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])}}
    key_bones_frames(rig, ["a", "b"], [10, 15], values)
    after = fcurves_of(rig)

    assert set(after) == set(before)  # no F-Curve added or lost
    for key, curve in before.items():
        bone, prop = key[0].split('"')[1], key[0].rsplit(".", 1)[1]
        if prop not in values.get(bone, {}):
            assert_same_curve(after[key], curve)  # other bones and other properties: untouched
            continue
        new = after[key]
        frames = new["co"][:, 0]
        np.testing.assert_array_equal(frames, [1, 10, 15, 20])  # replaced at 10, added at 15, no duplicate
        for frame in (1, 20):  # other frames kept exactly
            old_row = curve["co"][:, 0] == frame
            np.testing.assert_array_equal(new["co"][frames == frame], curve["co"][old_row])
        np.testing.assert_array_equal(new["co"][1:3, 1], np.float32(values[bone][prop][:, key[1]]))
        # The new key takes the interpolation of the key before it, as Blender's own keying does.
        assert new["interpolation"][2] == new["interpolation"][1] == before[key]["interpolation"][1]
    shaped_before, shaped_after = before[(path("a", "location"), 0)], after[(path("a", "location"), 0)]
    for handle in ("left", "right"):
        np.testing.assert_allclose(shaped_after[handle][1] - shaped_after["co"][1],
                                   shaped_before[handle][1] - shaped_before["co"][1], atol=1e-6)
    np.testing.assert_allclose(evaluated_values(rig, 15, "b", "rotation_euler"), [0.4, 0.5, 0.6], atol=1e-6)
    np.testing.assert_allclose(evaluated_values(rig, 10, "a", "location"), [1, 2, 3], atol=1e-6)


@pytest.mark.parametrize("frame", [1, 10, 20])
def test_one_frame_keyed_again_rewrites_that_key_alone(rig, frame):
    """A click keys one frame: on curves keyed at 1, 10 and 20 only the key at that frame takes the new value,
    its free handles moving with it; the other keys keep their frames and values. A frame between keys is
    added as a new key."""
    keyed_rig(rig)
    for fc in animating_fcurves(rig):
        if fc.data_path == path("a", "location"):
            point = next(p for p in fc.keyframe_points if p.co.x == frame)
            point.handle_left_type = point.handle_right_type = "FREE"
    before = fcurves_of(rig)
    location = np.array([[7.0, -8.0, 9.0]])
    key_bones_frames(rig, ["a"], [frame], {"a": {"location": location}})
    after = fcurves_of(rig)
    for key, curve in before.items():
        if key[0] != path("a", "location"):
            assert_same_curve(after[key], curve)
            continue
        new = after[key]
        at = list(curve["co"][:, 0]).index(frame)
        delta = np.float32(location[0, key[1]]) - curve["co"][at, 1]
        assert new["co"][at, 1] == np.float32(location[0, key[1]])
        for handle in ("left", "right"):
            np.testing.assert_allclose(new[handle][at], curve[handle][at] + [0.0, delta], atol=1e-5)
        others = np.arange(len(curve["co"])) != at
        np.testing.assert_array_equal(new["co"][others], curve["co"][others])
        np.testing.assert_array_equal(new["interpolation"], curve["interpolation"])
    key_bones_frames(rig, ["a"], [frame + 4], {"a": {"location": location}})
    np.testing.assert_array_equal(fcurves_of(rig)[(path("a", "location"), 0)]["co"][:, 0],
                                  sorted([1, 10, 20, frame + 4]))


def test_keying_the_same_frame_twice_replaces_the_key(rig):
    set_pose(rig, 0)
    key_bones(rig, ["c"], 3, channels=("rotation",))
    set_pose(rig, 1)
    key_bones(rig, ["c"], 3, channels=("rotation",))
    curves = fcurves_of(rig)
    assert set(curves) == {(path("c", "rotation_axis_angle"), i) for i in range(4)}
    for (_path, index), curve in curves.items():
        np.testing.assert_array_equal(curve["co"], [[3, np.float32(rig.pose.bones["c"].rotation_axis_angle[index])]])


def test_new_action_keeps_the_original_intact(rig):
    before = keyed_rig(rig)
    original = rig.animation_data.action
    values = {"a": {"location": np.array([[9.0, 8.0, 7.0]])}}
    action = key_bones_frames(rig, ["a"], [5], values, action_name="Adjusted")

    assert action.name == "Adjusted" and action != original
    assert rig.animation_data.action == action
    assert original.use_fake_user  # not lost on save now that the object uses the copy
    original_after = fcurves_of(rig, original)
    assert set(original_after) == set(before)
    for key, curve in before.items():
        assert_same_curve(original_after[key], curve)
    # The copy has everything else and the new key.
    copied = fcurves_of(rig)
    for key, curve in before.items():
        if key[0] != path("a", "location"):
            assert_same_curve(copied[key], curve)
        else:
            np.testing.assert_array_equal(copied[key]["co"][:, 0], [1, 5, 10, 20])
    np.testing.assert_allclose(evaluated_values(rig, 5, "a", "location"), [9, 8, 7], atol=1e-6)
    # Keying again under the same name goes on in the new action: no third action.
    actions = len(bpy.data.actions)
    assert key_bones(rig, ["a"], 6, action_name="Adjusted") == action
    assert len(bpy.data.actions) == actions
    assert_same_curve(fcurves_of(rig, original)[(path("a", "location"), 0)], before[(path("a", "location"), 0)])


def test_many_frames_at_once_into_an_empty_action(rig):
    frames = np.arange(1, 61, dtype=float)
    rng = np.random.default_rng(4)
    values = {"b": {"location": rng.normal(size=(60, 3)), "rotation_euler": rng.normal(size=(60, 3))},
              "c": {"rotation_axis_angle": rng.normal(size=(60, 4))}}
    key_bones_frames(rig, None, frames[::-1], {b: {p: v[::-1] for p, v in props.items()}
                                               for b, props in values.items()})
    curves = fcurves_of(rig)
    assert len(curves) == 10
    interpolation = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items[
        bpy.context.preferences.edit.keyframe_new_interpolation_type].value
    for bone, props in values.items():
        for prop, array in props.items():
            for index in range(array.shape[1]):
                curve = curves[(path(bone, prop), index)]
                np.testing.assert_array_equal(curve["co"][:, 0], frames)  # sorted
                np.testing.assert_array_equal(curve["co"][:, 1], array[:, index].astype(np.float32))
                assert np.all(curve["interpolation"] == interpolation)
    np.testing.assert_allclose(evaluated_values(rig, 30, "c", "rotation_axis_angle"),
                               values["c"]["rotation_axis_angle"][29], atol=1e-6)


def test_bad_input_writes_nothing(rig):
    with pytest.raises(AdjustError, match="no pose bone named 'nope'"):
        key_bones(rig, ["a", "nope"], 1)
    with pytest.raises(ValueError, match="shape"):
        key_bones_frames(rig, ["a"], [1, 2], {"a": {"location": np.zeros((3, 3))}})
    with pytest.raises(ValueError, match="NaN"):
        key_bones_frames(rig, ["a"], [1], {"a": {"location": [[0, np.nan, 0]]}})
    with pytest.raises(ValueError, match="same"):
        key_bones_frames(rig, ["a"], [1, 1.001], {"a": {"location": np.zeros((2, 3))}})
    assert rig.animation_data is None or rig.animation_data.action is None


def test_undo_restores_pose_and_keys(rig):
    before_keys = keyed_rig(rig)
    bpy.context.scene.frame_set(10)
    before_pose = pose_values(rig)
    bpy.ops.ed.undo_push(message="before adjust")

    snapshot = read_pose(rig)
    requested = snapshot.matrices[:2].copy()
    requested[:, :3, 3] += (0.3, -0.2, 0.1)
    channels = world_rotations_to_channels(rig, snapshot, requested, ["a", "b"])
    apply_channels(rig, channels)
    key_bones(rig, ["a", "b"], 10)
    key_bones(rig, ["a"], 12)
    changed = fcurves_of(rig)
    assert pose_values(rig) != before_pose
    assert any(len(changed[key]["co"]) != len(curve["co"]) for key, curve in before_keys.items())
    bpy.ops.ed.undo_push(message="adjust")

    bpy.ops.ed.undo()
    rig = bpy.data.objects["Rig"]  # undo reloads the data: old references are gone
    assert pose_values(rig) == before_pose
    after = fcurves_of(rig)
    assert set(after) == set(before_keys)
    for key, curve in before_keys.items():
        assert_same_curve(after[key], curve)
