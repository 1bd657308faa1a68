"""Arms without a hand bone ("Map Bones maps every group right on any humanoid whose limbs are a chain"),
through the registered extension on the Rigify basic metarig with its hand bones deleted:

- ``robot``: nothing below the forearms (the Godot platformer robot's arms);
- ``fingers``: four two-bone fingers fanning out of each forearm where the hand's head was (Quaternius' rigs).

The wrist is then where the forearm ends: here its tail, which is where the deleted hand's head was. Map Bones maps
the arms with no hand bone and says so; Create Targets puts the hand's target on that wrist; a near Adjust Pose
brings it onto its target and keys only that arm (the fingers ride on the forearm); a hand target asking for its
rotation is refused in one line; a CMU walk retargets onto it with the forearms along the source's. Every figure is
measured on the pose Blender evaluates, the wrist as the deleted hand's head carried by the forearm's pose.
"""

import contextlib
import importlib
import io

import bpy
import numpy as np
import pytest
from mathutils import Vector

from tests.helpers import rig_measures as rm
from tests.helpers.blender_data import bone_map, evaluated
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR
from tests.helpers.rig_building import add_metarig

SIDES = ("L", "R")
FINGERS = ((0.03, 0.0, 0.0), (0.025, -0.02, 0.0), (0.025, 0.02, 0.0), (0.015, -0.03, -0.01))  # first bone's step


def handless_metarig(kind):
    """The basic metarig with hand.L/.R deleted (``fingers``: four fingers added under each forearm, starting at
    the hand's head); returns (armature, {side: the wrist in the forearm's rest frame (4,) homogeneous})."""
    obj = add_metarig()
    bpy.ops.object.mode_set(mode='EDIT')
    bones = obj.data.edit_bones
    wrists = {}
    for s in SIDES:
        hand, forearm = bones[f"hand.{s}"], bones[f"forearm.{s}"]
        wrist, sign = hand.head.copy(), 1.0 if s == "L" else -1.0
        if kind == "fingers":
            for k, (x, y, z) in enumerate(FINGERS):
                step = Vector((sign * x, y, z))
                tip = wrist + step
                for j in range(2):
                    finger = bones.new(f"finger{k}.{j}.{s}")
                    finger.head, finger.tail = (wrist if j == 0 else tip), (tip if j == 0 else tip + step)
                    finger.parent = forearm if j == 0 else bones[f"finger{k}.0.{s}"]
                    finger.use_connect = j == 1
        bones.remove(hand)
        wrists[s] = wrist
    bpy.ops.object.mode_set(mode='OBJECT')
    local = {s: np.linalg.inv(np.array(obj.data.bones[f"forearm.{s}"].matrix_local)) @ np.append(wrists[s], 1.0)
             for s in SIDES}
    return obj, local


def wrist(obj, local, side):
    """World position of the wrist (the deleted hand's head) carried by the forearm as Blender evaluates it."""
    ev = evaluated(obj)
    return (np.array(ev.matrix_world) @ np.array(ev.pose.bones[f"forearm.{side}"].matrix) @ local[side])[:3]


@pytest.fixture(params=["robot", "fingers"])
def rig(request):
    return (request.param, *handless_metarig(request.param))


def test_map_bones_maps_the_arms_with_no_hand_bone(rig):
    kind, obj, _local = rig
    bpy.ops.fullbody_adjust.map_bones()
    groups = bone_map(obj)
    for s in SIDES:
        assert groups[f"arm.{s}"] == [f"shoulder.{s}", f"upper_arm.{s}", f"forearm.{s}"]
        assert groups[f"hand.{s}"] == [""]  # the hand's row, with no bone
        assert groups[f"leg.{s}"] == [f"thigh.{s}", f"shin.{s}"] and groups[f"foot.{s}"] == [f"foot.{s}"]
    assert not any(b.startswith("finger") for bones in groups.values() for b in bones)


def test_create_targets_puts_the_hand_target_on_the_wrist(rig, extension_module_name):
    _kind, obj, local = rig
    obj.pose.bones["forearm.L"].rotation_mode = 'XYZ'
    obj.pose.bones["forearm.L"].rotation_euler = (0.4, 0.0, 0.3)  # the wrist is carried by the posed forearm
    bpy.ops.fullbody_adjust.create_targets()
    batch = importlib.import_module(f"{extension_module_name}.bridge.files")
    effectors = batch.effector_positions(obj, [bpy.context.scene.frame_current])[0]  # the command line's preview
    for k, s in enumerate(SIDES):
        slot = next(t for t in obj.fullbody_adjust.targets if t.effector == f"hand.{s}")
        assert slot.enabled
        assert np.linalg.norm(np.array(slot.target.matrix_world.translation) - wrist(obj, local, s)) < 1e-5
        assert np.linalg.norm(effectors[k] - wrist(obj, local, s)) < 1e-5


def test_a_near_target_moves_the_wrist_onto_it_and_keys_only_that_arm(rig):
    kind, obj, local = rig
    bpy.ops.fullbody_adjust.create_targets()
    next(t for t in obj.fullbody_adjust.targets if t.effector == "head").enabled = False
    shoulder, elbow = rm.world_heads(obj, ["upper_arm.R", "forearm.R"])
    start = wrist(obj, local, "R")
    reach = np.linalg.norm(elbow - shoulder) + np.linalg.norm(start - elbow)
    direction = np.array([-0.3, -0.6, -0.5])  # out to the right, in front, down
    goal = shoulder + 0.7 * reach * direction / np.linalg.norm(direction)
    slot = next(t for t in obj.fullbody_adjust.targets if t.effector == "hand.R")
    slot.target.location = goal
    bpy.context.view_layer.update()
    before_rot, before_keys = rm.local_rotations(obj), rm.keys_snapshot(obj)
    others_before = {s: wrist(obj, local, s) for s in ("L",)}
    bpy.ops.fullbody_adjust.adjust_pose()
    assert np.linalg.norm(wrist(obj, local, "R") - goal) < 1e-4  # the wrist, not any bone's head, is on it
    assert np.linalg.norm(start - goal) > 0.1 * reach  # ... and it had to move to get there
    changes = rm.rotation_changes(before_rot, rm.local_rotations(obj))
    arm = {"upper_arm.R", "forearm.R"}
    assert max(d for b, d in changes.items() if b not in arm) < 0.01, \
        {b: d for b, d in changes.items() if b not in arm and d >= 0.01}  # fingers ride on the forearm
    assert set(rm.keyed_bones(before_keys, rm.keys_snapshot(obj))) <= arm | {"shoulder.R"}
    assert np.linalg.norm(wrist(obj, local, "L") - others_before["L"]) < 1e-6


def test_a_hand_target_that_asks_for_its_rotation_is_refused_in_one_line(rig):
    _kind, obj, _local = rig
    bpy.ops.fullbody_adjust.create_targets()
    slot = next(t for t in obj.fullbody_adjust.targets if t.effector == "hand.L")
    slot.use_rotation = True
    slot.target.location.z -= 0.05
    with pytest.raises(RuntimeError) as caught:
        bpy.ops.fullbody_adjust.adjust_pose()
    message = str(caught.value).strip()
    assert "\n" not in message
    assert "The hand.L target of 'metarig' asks for its rotation, but the arm has no hand bone to turn (the wrist " \
           "is the end of 'forearm.L'): switch Rotation off in that slot" in message


def test_a_walk_retargets_with_the_forearms_along_the_sources(rig, tmp_path, extension_module_name):
    _kind, obj, local = rig
    cli = importlib.import_module(f"{extension_module_name}.cli")
    if "io_anim_bvh" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="io_anim_bvh")
    bpy.ops.import_anim.bvh(filepath=str(MOCAP_DIR / "cmu_07_01_walk.bvh"), global_scale=CMU_SCALE,
                            update_scene_fps=False, update_scene_duration=True, use_fps_scale=True)
    source = bpy.context.active_object
    source.name = "Source"
    last = int(np.floor(source.animation_data.action.frame_range[1]))
    path_in, path_out = tmp_path / "walk.blend", tmp_path / "walk_out.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path_in))
    with contextlib.redirect_stderr(io.StringIO()) as said:
        code = cli.main(["retarget", str(path_in), "--source", "Source", "--target", obj.name, "--frame-start", "2",
                         "--frame-end", str(last), "--floor", "0", "--output", str(path_out), "--quiet"])
    assert code == 0, said.getvalue()[-400:]
    bpy.ops.wm.open_mainfile(filepath=str(path_out), load_ui=False)
    obj, source = bpy.data.objects["metarig"], bpy.data.objects["Source"]
    joints, source_joints = {}, {}
    for frame in range(2, last + 1, 2):
        bpy.context.scene.frame_set(frame)
        for s, word in (("L", "Left"), ("R", "Right")):
            hip, elbow = rm.world_heads(obj, [f"thigh.{s}", f"forearm.{s}"])
            for role, point in (("hip", hip), ("elbow", elbow), ("wrist", wrist(obj, local, s))):
                joints.setdefault(f"{role}.{s}", []).append(point)
            for role, point in zip(("hip", "elbow", "wrist"), rm.world_heads(
                    source, [f"{word}UpLeg", f"{word}ForeArm", f"{word}Hand"])):
                source_joints.setdefault(f"{role}.{s}", []).append(point)
    angles = rm.limb_direction_angles({k: np.array(v) for k, v in joints.items()},
                                      {k: np.array(v) for k, v in source_joints.items()})
    assert angles.shape[1] == 2  # the two forearms, each in its body's frame
    assert np.median(angles) < 5.0, np.median(angles)
