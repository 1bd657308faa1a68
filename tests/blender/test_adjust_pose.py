"""bpy.ops.fullbody_adjust.adjust_pose end to end, on the Rigify basic (29 bones) and full
(159 bones) metarigs and on the CMU walk clip imported with Blender's BVH importer.

Every target is reachable by construction (placed within the reach the rig has, computed from its own bones) and
the solver must say so in the operator's report; every assertion is measured on the pose Blender evaluates after
the operator, against numbers computed from the rig before it.
"""

import importlib
from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from .scene_tools import (LAYERED_ACTIONS, RIG_KINDS, Pose, add_box, add_rig, animating_fcurves, body_axes, body_joints,
                          bone_map, chain_joints, chain_length, drop_frame, file_state, inside_box, keys_at, keys_state,
                          parse_report, place, pose_channels, residuals, slot, without_derived_handles)

# A met target is within this fraction of the rig's height.
REACH = 1e-4
# Bone lengths are read back from Blender's float32 pose matrices, and Rigify's own rest matrices are off
# orthonormal by up to 6e-6, so a bone that turns shows a length a few 1e-6 (relative) off: allow 1e-5.
LENGTH = 1e-5
CMU_FRAME = 60  # mid-stride in the walk clip (frame 1 is a T-pose)
KEY_FRAME = 5  # the basic rig's own keys are at 1 and 10


def adjust(capfd, *args, **props):
    """Run the operator; (targets met, targets, largest residual) from its report."""
    capfd.readouterr()
    result = bpy.ops.fullbody_adjust.adjust_pose(*args, **props)
    assert result == {'FINISHED'}
    return parse_report(capfd.readouterr().out)


def rig_with_targets(kind):
    obj = add_rig(kind)
    if kind == "cmu":
        bpy.context.scene.frame_set(CMU_FRAME)
    bpy.ops.fullbody_adjust.create_targets()
    return obj


def reach_left_hand(obj, pose, task):
    """Place the left hand's target for `task` (armature-space geometry, placed in the world) and return the
    enabled targets' effectors. Feet targets stay at the current ankles.

    arm:    0.8 of the arm's length from its base, up and forward of the current wrist: the arm alone serves;
    trunk:  1.15 arm lengths from the arm's base, forward and down: the trunk must bend (right hand off, since
            two hand targets can pull the chest apart);
    pelvis: just above the floor in front of the left foot: beyond what bending the trunk reaches, so the
            pelvis must come down."""
    up, left, forward = body_axes(obj, pose)
    arm = chain_joints(obj, pose, "arm.L")
    reach, base = chain_length(arm), arm[0]
    if task == "arm":
        direction = (arm[-1] - base) / np.linalg.norm(arm[-1] - base) + 0.5 * up + 0.3 * forward
        goal = base + 0.8 * reach * direction / np.linalg.norm(direction)
    elif task == "trunk":
        direction = forward - 0.3 * up + 0.2 * left
        goal = base + 1.15 * reach * direction / np.linalg.norm(direction)
    else:
        goal = pose.head(bone_map(obj)["foot.L"][0]) + 0.4 * reach * forward + 0.1 * reach * up
    if task != "arm":
        slot(obj, "hand.R").enabled = False
    place(slot(obj, "hand.L").target, pose.to_world(goal))
    return {s.effector for s in obj.fullbody_adjust.targets if s.enabled}


def assert_lengths_kept(before, after):
    np.testing.assert_array_less(np.abs(after.lengths - before.lengths), LENGTH * before.lengths)


def assert_met(obj, report, enabled, height):
    """Every enabled target met, by the solver's word and by measurement; the report's largest residual is
    the measured one."""
    met, tasks, largest = report
    assert (met, tasks) == (len(enabled), len(enabled))
    measured = residuals(obj)
    assert set(measured) == enabled
    assert max(measured.values()) <= REACH * height, measured
    assert largest == pytest.approx(max(measured.values()), rel=1e-3, abs=1e-12)


# --- reaching --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", RIG_KINDS)
@pytest.mark.parametrize("task", ("arm", "trunk", "pelvis"))
def test_reachable_target_is_met(kind, task, capfd):
    obj = rig_with_targets(kind)
    before = Pose(obj)
    enabled = reach_left_hand(obj, before, task)

    report = adjust(capfd)

    after = Pose(obj)
    assert_met(obj, report, enabled, before.height())
    assert_lengths_kept(before, after)
    root = bone_map(obj)["root"][0]
    root_moved = np.linalg.norm(after.head(root) - before.head(root))
    sc_moved = np.linalg.norm(chain_joints(obj, after, "trunk")[-1] - chain_joints(obj, before, "trunk")[-1])
    if task == "arm":  # fewest moved joints: the trunk and the pelvis stay exactly
        trunk = [before.index[b] for b in bone_map(obj)["trunk"] + [root]]
        np.testing.assert_array_equal(after.matrices[trunk], before.matrices[trunk])
    elif task == "trunk":
        assert root_moved == 0.0 and sc_moved > 0.05 * before.height()
    else:
        assert root_moved > 0.05 * before.height()


@pytest.mark.parametrize("kind", RIG_KINDS)
def test_planted_feet_keep_their_world_orientation(kind, capfd):
    """The pelvis comes down and the shins turn: the feet, planted where they stand, keep their world
    orientation (they are keyed although their own world transform did not change), so the toes stay put."""
    obj = rig_with_targets(kind)
    before = Pose(obj)
    reach_left_hand(obj, before, "pelvis")
    adjust(capfd)
    after = Pose(obj)
    groups = bone_map(obj)
    for side in "LR":
        shin = before.index[groups[f"leg.{side}"][-1]]
        assert not np.allclose(after.matrices[shin, :3, :3], before.matrices[shin, :3, :3], atol=1e-3)
        foot = groups[f"foot.{side}"][0]
        below = [i for i, name in enumerate(before.names) if name == foot
                 or obj.data.bones[name].parent_recursive and foot in {b.name for b in obj.data.bones[name].parent_recursive}]
        np.testing.assert_allclose(after.matrices[below], before.matrices[below], atol=1e-5 * before.height())


@pytest.mark.parametrize("transform", ("moved_rotated_scaled", "non_uniform_scale"))
def test_object_transform(transform, capfd):
    obj = rig_with_targets("basic")
    obj.location = (1.5, -2.0, 0.4)
    obj.rotation_euler = (0.3, -0.2, 1.1)
    obj.scale = (1.7, 1.7, 1.7) if transform == "moved_rotated_scaled" else (1.3, 0.7, 1.1)
    bpy.ops.fullbody_adjust.create_targets(reset=True)  # targets back on the moved wrists and ankles
    before = Pose(obj)
    enabled = reach_left_hand(obj, before, "trunk")

    report = adjust(capfd)

    after = Pose(obj)
    assert_met(obj, report, enabled, before.height())
    assert_lengths_kept(before, after)
    np.testing.assert_array_equal(after.matrix_world, before.matrix_world)


def test_pose_mode(capfd):
    obj = rig_with_targets("full")
    bpy.ops.object.mode_set(mode='POSE')
    before = Pose(obj)
    enabled = reach_left_hand(obj, before, "trunk")

    report = adjust(capfd)

    assert obj.mode == 'POSE'
    assert_met(obj, report, enabled, before.height())


def adjusted_from(adjustment, obj, rest):
    """The pose put back to ``rest`` (pose_channels) and adjusted without keys: (the evaluated pose's matrices,
    the outcome)."""
    for name, (_mode, location, quaternion, euler, _axis_angle, _scale) in rest.items():
        pb = obj.pose.bones[name]
        pb.location, pb.rotation_quaternion, pb.rotation_euler = location, quaternion, euler
    outcome = adjustment.adjust_pose(bpy.context, obj, adjustment.Options(insert_keys=False))
    return Pose(obj).matrices, outcome

def test_obstacle_on_the_elbows_way(extension_module_name):
    """A box where the elbow would go without it: after adjusting, no joint of any chain is inside it, and the
    hand still reaches its target."""
    adjustment = importlib.import_module(f"{extension_module_name}.bridge.adjustment")
    obj = rig_with_targets("basic")
    rest = pose_channels(obj)
    before = Pose(obj)
    enabled = reach_left_hand(obj, before, "arm")
    adjustment.adjust_pose(bpy.context, obj, adjustment.Options(insert_keys=False))
    free = Pose(obj)
    elbow = free.to_world(free.head(bone_map(obj)["arm.L"][-1]))
    assert np.linalg.norm(elbow - before.to_world(before.head(bone_map(obj)["arm.L"][-1]))) > 0.05  # it moves
    for name, (_mode, location, quaternion, euler, _axis_angle, _scale) in rest.items():  # back to the start
        pb = obj.pose.bones[name]
        pb.location, pb.rotation_quaternion, pb.rotation_euler = location, quaternion, euler
    box = add_box(obj, elbow, 0.08)

    outcome = adjustment.adjust_pose(bpy.context, obj)

    after = Pose(obj)
    joints = after.to_world(body_joints(obj, after))
    assert not inside_box(box, joints).any(), "a joint is inside the obstacle"
    assert int(outcome.joints_inside.sum()) == 0 and int(outcome.segments_crossing.sum()) == 0
    assert_met(obj, (int(outcome.met[outcome.constrained].sum()), int(outcome.constrained.sum()),
                     float(np.nanmax(outcome.residuals))), enabled, before.height())
    assert_lengths_kept(before, after)


def test_meshes_far_from_the_character_change_nothing(extension_module_name):
    """A set of forty meshes (some rotated) far from the character: they are obstacles (visible meshes), but no
    bone can reach them, so Adjust Pose gives the pose it gives without them, bit for bit."""
    adjustment = importlib.import_module(f"{extension_module_name}.bridge.adjustment")
    obj = rig_with_targets("basic")
    rest = pose_channels(obj)
    reach_left_hand(obj, Pose(obj), "arm")

    def adjusted():
        return adjusted_from(adjustment, obj, rest)

    free, _outcome = adjusted()
    solved = Pose(obj)
    add_box(obj, solved.to_world(solved.head(bone_map(obj)["arm.L"][-1])), 0.08)  # where the elbow goes without it
    alone, outcome_alone = adjusted()
    assert np.abs(alone - free).max() > 1e-3  # the box near the arm counts
    for k in range(40):
        far = add_box(obj, (30.0 + 2.0 * k, -40.0, 1.0), 1.5)
        far.rotation_euler = (0.3 * k, 0.0, 0.7) if k % 2 else (0.0, 0.0, 0.0)
    bpy.context.view_layer.update()
    among, outcome_among = adjusted()
    np.testing.assert_array_equal(among, alone)
    np.testing.assert_array_equal(outcome_among.residuals, outcome_alone.residuals)
    assert outcome_among.moved_bones == outcome_alone.moved_bones



def test_an_obstacle_stays_in_the_world_when_the_armature_moves(extension_module_name):
    """A click reuses the boxes it built while the obstacles and the armature's transform stay the same. The
    armature moved away from a box by its elbow, its targets with it, no longer bends around that box: the pose
    is the one solved without the box."""
    adjustment = importlib.import_module(f"{extension_module_name}.bridge.adjustment")
    obj = rig_with_targets("basic")
    rest = pose_channels(obj)
    reach_left_hand(obj, Pose(obj), "arm")

    def adjusted():
        return adjusted_from(adjustment, obj, rest)[0]

    free = adjusted()
    solved = Pose(obj)
    add_box(obj, solved.to_world(solved.head(bone_map(obj)["arm.L"][-1])), 0.08)  # where the elbow goes without it
    bpy.context.view_layer.update()
    assert np.abs(adjusted() - free).max() > 1e-3  # the box counts
    obj.location.x += 2.0
    for target_slot in obj.fullbody_adjust.targets:
        if target_slot.target is not None:
            target_slot.target.location.x += 2.0
    bpy.context.view_layer.update()
    np.testing.assert_allclose(adjusted(), free, rtol=0.0, atol=1e-6)

# --- keys ------------------------------------------------------------------------------------------------------


def keyed_metarig(kind="basic"):
    """A Rigify metarig with keys at frames 1 and 10 on arm, trunk and root bones and on bones outside every
    group (the breast; on the full rig also a finger), each a different pose; the upper arm's keys have FREE
    handles."""
    obj = add_rig(kind)
    rng = np.random.default_rng(5)
    keyed = ["upper_arm.L", "forearm.L", "spine.002", "breast.L"] + (["f_index.02.L"] if kind == "full" else [])
    for frame in (1, 10):
        for name in keyed:
            pb = obj.pose.bones[name]
            angles = rng.uniform(-0.2, 0.2, 3)
            if pb.rotation_mode == 'QUATERNION':
                pb.rotation_quaternion = (1.0, *angles)
                pb.rotation_quaternion.normalize()
                pb.keyframe_insert("rotation_quaternion", frame=frame)
            else:
                pb.rotation_euler = angles
                pb.keyframe_insert("rotation_euler", frame=frame)
        obj.pose.bones["spine"].location = rng.uniform(-0.02, 0.02, 3)
        obj.pose.bones["spine"].keyframe_insert("location", frame=frame)
    for fcurve in animating_fcurves(obj):  # user-set handles on the upper arm, which the adjustment turns
        if "upper_arm.L" in fcurve.data_path:
            for key in fcurve.keyframe_points:
                key.handle_left_type = key.handle_right_type = 'FREE'
                key.handle_left = (key.co.x - 2.0, key.co.y + 0.3)
                key.handle_right = (key.co.x + 1.5, key.co.y - 0.2)
    return obj


@pytest.mark.parametrize("kind", RIG_KINDS)
def test_keys_on_other_frames_and_bones_kept(kind, capfd):
    """Keys at other frames, and F-Curves of bones that did not move, stay bit for bit; each moved bone has a key
    at the current frame, stored where this Blender animates from, and the keys give back the adjusted pose."""
    if kind != "cmu":
        obj, frame = keyed_metarig(kind), KEY_FRAME
        bpy.context.scene.frame_set(frame)
        bpy.ops.fullbody_adjust.create_targets()
    else:
        obj, frame = rig_with_targets("cmu"), CMU_FRAME
    before_pose = Pose(obj)
    enabled = reach_left_hand(obj, before_pose, "arm")
    before_channels = pose_channels(obj)
    before_keys = keys_state(obj)
    other_frame = 30 if kind == "cmu" else 1
    bpy.context.scene.frame_set(other_frame)
    other_channels = pose_channels(obj)
    bpy.context.scene.frame_set(frame)

    report = adjust(capfd)

    after_channels = pose_channels(obj)
    moved = {name for name in after_channels if after_channels[name] != before_channels[name]}
    assert bone_map(obj)["arm.L"][-1] in moved and moved <= {b for bones in bone_map(obj).values() for b in bones}
    after_keys = keys_state(obj)
    assert set(before_keys) <= set(after_keys)
    for path, before in before_keys.items():
        bone = path[0].split('"')[1]
        if bone in moved:
            assert (without_derived_handles(drop_frame(after_keys[path], frame))
                    == without_derived_handles(drop_frame(before, frame))), path
        else:
            assert after_keys[path] == before, path
    curves = {(fc.data_path, fc.array_index): fc for fc in animating_fcurves(obj)}
    for bone in moved:
        keyed = [fc for (path, _), fc in curves.items() if path.startswith(f'pose.bones["{bone}"].rotation')]
        assert keyed and all(len(keys_at(fc, frame)) == 1 for fc in keyed), bone
    forearm = obj.pose.bones[bone_map(obj)["arm.L"][-1]]
    rotation = "rotation_quaternion" if forearm.rotation_mode == 'QUATERNION' else "rotation_euler"
    path = f'pose.bones["{forearm.name}"].{rotation}'
    action = obj.animation_data.action
    if LAYERED_ACTIONS:  # 4.4+: in the channelbag of the slot the armature animates through
        from bpy_extras import anim_utils

        fcurve = anim_utils.action_get_channelbag_for_slot(action, obj.animation_data.action_slot).fcurves.find(path)
    else:  # 4.2: the action's own (legacy) F-Curves
        fcurve = action.fcurves.find(path)
    assert fcurve is not None and len(keys_at(fcurve, frame)) == 1

    # On another frame the bones keyed before pose as before (a bone keyed for the first time holds its one
    # key on every frame, as with Blender's own keying).
    bpy.context.scene.frame_set(other_frame)
    keyed_before = {path.split('"')[1] for path, _ in before_keys}
    after_other = pose_channels(obj)
    assert {b: after_other[b] for b in keyed_before} == {b: other_channels[b] for b in keyed_before}
    bpy.context.scene.frame_set(frame)
    assert_met(obj, report, enabled, before_pose.height())


@pytest.mark.parametrize("keyed", (False, True), ids=("new_action", "keyed"))
def test_undo_restores_pose_and_keys(keyed, capfd):
    if keyed:
        obj = keyed_metarig()
        bpy.context.scene.frame_set(KEY_FRAME)
        bpy.ops.fullbody_adjust.create_targets()
    else:
        obj = rig_with_targets("basic")
    reach_left_hand(obj, Pose(obj), "trunk")
    before = file_state()
    bpy.ops.ed.undo_push(message="before adjusting")

    adjust(capfd, 'EXEC_DEFAULT', True)  # True: push an undo step, as the UI does for an UNDO operator
    assert file_state() != before

    bpy.ops.ed.undo()
    assert file_state() == before


# --- redo panel and report -------------------------------------------------------------------------------------


def test_redo_panel_shows_main_settings():
    operator = bpy.types.FULLBODY_ADJUST_OT_adjust_pose
    assert {'REGISTER', 'UNDO'} <= set(operator.bl_options)
    properties = bpy.ops.fullbody_adjust.adjust_pose.get_rna_type().properties
    main = ("variant", "margin", "use_joint_limits", "keep_hand_orientation")
    assert set(main) <= set(properties.keys())
    assert {item.identifier for item in properties["variant"].enum_items} == {'FABRIK', 'WEIGHTED', 'PRIORITY'}
    # Not remembered from the last run (Blender would mark them set): each run starts from the stored settings.
    assert all(properties[name].is_skip_save for name in main)
    # The same properties as the stored settings: texts, defaults and ranges.
    stored = bpy.types.Object.bl_rna.properties["fullbody_adjust"].fixed_type.properties
    for name in main:
        for attribute in ("name", "description", "default", "hard_min", "hard_max", "subtype", "unit"):
            if hasattr(stored[name], attribute):
                assert getattr(properties[name], attribute) == getattr(stored[name], attribute), (name, attribute)
    drawn = []
    layout = SimpleNamespace(prop=lambda data, name, **kw: drawn.append(name), use_property_split=False)
    operator.draw(SimpleNamespace(layout=layout), bpy.context)
    assert tuple(drawn) == main


def conflicting_hands(capfd, variant=None, stored='PRIORITY'):
    """The hands pulled 2 m apart (no pose meets both), the left one within its arm's reach and with the higher
    priority; `variant` passed to the operator, `stored` on the armature. Returns {effector: residual} and the
    rig's height."""
    bpy.ops.wm.read_homefile(use_empty=True)
    obj = rig_with_targets("basic")
    obj.fullbody_adjust.variant = stored
    pose = Pose(obj)
    _up, left, _forward = body_axes(obj, pose)
    arm = chain_joints(obj, pose, "arm.L")
    goal = arm[0] + 0.95 * chain_length(arm) * left  # the left arm alone reaches it
    place(slot(obj, "hand.L").target, pose.to_world(goal))
    place(slot(obj, "hand.R").target, pose.to_world(goal - 2.0 * left))
    slot(obj, "hand.L").priority = 5
    _met, tasks, _largest = adjust(capfd, **({} if variant is None else {"variant": variant}))
    assert tasks == 4
    return residuals(obj), pose.height()


def test_variant_decides_conflicting_targets(capfd):
    priority, height = conflicting_hands(capfd, 'PRIORITY', stored='FABRIK')
    fabrik, _ = conflicting_hands(capfd, 'FABRIK')
    assert priority["hand.L"] <= REACH * height  # the higher priority wins outright
    assert fabrik["hand.L"] > 100 * REACH * height  # the plain centroid serves neither hand
    assert fabrik["hand.R"] < priority["hand.R"]
    assert conflicting_hands(capfd, stored='FABRIK')[0] == fabrik  # not passed: the armature's setting counts


@pytest.mark.parametrize("keep", (True, False))
def test_keep_hand_orientation(keep, capfd):
    obj = rig_with_targets("basic")
    before = Pose(obj)
    enabled = reach_left_hand(obj, before, "arm")
    hand = before.index["hand.L"]
    hand_channels = pose_channels(obj)["hand.L"]

    report = adjust(capfd, keep_hand_orientation=keep)

    after = Pose(obj)
    assert_met(obj, report, enabled, before.height())
    turn = np.abs(after.matrices[hand, :3, :3] - before.matrices[hand, :3, :3]).max()
    if keep:
        assert turn < 1e-5
    else:
        assert turn > 1e-2  # it follows the forearm, keeping its local rotation
        assert pose_channels(obj)["hand.L"] == hand_channels


def test_report_counts_an_unreachable_target(capfd):
    obj = rig_with_targets("basic")
    pose = Pose(obj)
    up, left, _forward = body_axes(obj, pose)
    place(slot(obj, "hand.L").target, pose.to_world(pose.head("hand.L") + 3.0 * pose.height() * (left + up)))
    slot(obj, "hand.R").priority = 3  # served before the left hand, which pulls the chest its way

    met, tasks, largest = adjust(capfd)

    measured = residuals(obj)
    assert (met, tasks) == (3, 4)
    assert max(measured[e] for e in ("hand.R", "foot.L", "foot.R")) <= REACH * pose.height()
    assert largest == pytest.approx(measured["hand.L"], rel=1e-3)
    assert measured["hand.L"] > 2.0 * pose.height()
    assert "Warning" not in capfd.readouterr().out  # beyond reach is not a miss: INFO


def test_a_target_missed_within_reach_is_a_warning(capfd):
    """A left-hand target within the arm's reach, but the arm, clavicle and trunk bones have their IK X and Z
    locked: the hand stops short, and the report is a WARNING naming the effector and its residual, as the
    command line exits 1 for the same result."""
    obj = rig_with_targets("basic")
    for name in ("forearm.L", "upper_arm.L", "shoulder.L", "spine.001", "spine.002", "spine.003"):
        obj.pose.bones[name].lock_ik_x = obj.pose.bones[name].lock_ik_z = True
    pose = Pose(obj)
    reach_left_hand(obj, pose, "arm")

    capfd.readouterr()
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    out = capfd.readouterr().out
    missed = residuals(obj)["hand.L"]
    assert missed > 100 * REACH * pose.height()
    assert "Warning: hand.L missed its target within reach by" in out, out
    reported = float(out.split("within reach by ")[1].split()[0])
    assert reported == pytest.approx(missed, rel=1e-2)


def test_rig_without_neck_bones(capfd):
    """A head mapped without neck bones (many game characters) serves no head target, yet the rig adjusts; a
    head target switched on anyway gets one line naming the slot."""
    obj = rig_with_targets("basic")
    items = obj.fullbody_adjust.bone_map
    for index in reversed(range(len(items))):  # the head group without its neck bones, as a user may map it
        if items[index].group == "head" and items[index].bone != bone_map(obj)["head"][-1]:
            items.remove(index)
    assert len(bone_map(obj)["head"]) == 1
    before = Pose(obj)
    enabled = reach_left_hand(obj, before, "arm")
    assert_met(obj, adjust(capfd), enabled, before.height())
    head_slot = slot(obj, "head")
    head_slot.target = slot(obj, "hand.L").target
    head_slot.enabled = True
    with pytest.raises(RuntimeError, match="head target of 'metarig' needs neck bones"):
        bpy.ops.fullbody_adjust.adjust_pose()
