"""Live Adjust through the registered extension on the basic metarig: the handlers re-solve when a target
moves or the frame changes, show the pose without keys, Key Pose keys it, and turning Live off returns to the
keyed pose. Every distance is measured on the pose Blender evaluates, against the target as evaluated."""

import importlib

import bpy
import numpy as np
import pytest

from .scene_tools import (Pose, add_box, add_rig, animating_fcurves, bone_map, body_axes, chain_joints,
                          chain_length, drop_frame, inside_box, keys_at, keys_state, place, pose_channels, residuals,
                          slot, without_derived_handles)
from .test_adjust_pose import KEY_FRAME, keyed_metarig, reach_left_hand

# A met target is within this fraction of the rig's height (as for Adjust Pose).
REACH = 1e-4


@pytest.fixture
def live(extension_module_name, monkeypatch):
    """The Live module, its solves counted per armature (see solves)."""
    live = importlib.import_module(f"{extension_module_name}.bridge.live")
    solve = live.adjustment.adjust_pose
    _live_solves.clear()

    def counted(context, obj, options, *args, **kwargs):
        if options is live.LIVE_OPTIONS:  # Live's own solve, not an operator's
            _live_solves[obj.as_pointer()] = _live_solves.get(obj.as_pointer(), 0) + 1
        return solve(context, obj, options, *args, **kwargs)
    monkeypatch.setattr(live.adjustment, "adjust_pose", counted)
    return live


_live_solves = {}  # armature's as_pointer() -> Live solves of it in this test


def live_rig(keyed=False):
    """The basic metarig with targets at its wrists and ankles (keyed: with keys at 1 and 10, at KEY_FRAME)."""
    if keyed:
        obj = keyed_metarig()
        bpy.context.scene.frame_set(KEY_FRAME)
    else:
        obj = add_rig("basic")
    bpy.ops.fullbody_adjust.create_targets()
    return obj


def hand_distance(obj):
    return residuals(obj)["hand.L"]


def move_hand_target(obj, pose=None):
    """Put the left hand's target where the arm alone reaches (forward and up of the wrist); return its
    world position."""
    pose = pose or Pose(obj)
    reach_left_hand(obj, pose, "arm")
    return np.array(slot(obj, "hand.L").target.matrix_world.translation)


def live_after_a_target_move(keyed=False):
    """live_rig with Live on and the left hand's target moved (move_hand_target), the view layer updated."""
    obj = live_rig(keyed)
    obj.fullbody_adjust.live = True
    move_hand_target(obj)
    bpy.context.view_layer.update()
    return obj


def solves(live, obj):
    """How many times Live solved the armature ``obj`` so far in this test (followed through a rename)."""
    return _live_solves.get(obj.as_pointer(), 0)


def test_moving_a_target_solves_without_keys(live):
    obj = live_rig(keyed=True)
    start = Pose(obj)
    height = start.height()
    keys = keys_state(obj)
    obj.fullbody_adjust.live = True
    assert hand_distance(obj) < REACH * height  # the targets sit on the wrists: nothing to do yet

    move_hand_target(obj, start)
    far = float(np.linalg.norm(start.to_world(start.head("hand.L")) - np.array(
        slot(obj, "hand.L").target.matrix_world.translation)))
    assert far > 0.05 * height  # the target really moved away from the wrist
    bpy.context.view_layer.update()

    assert hand_distance(obj) < REACH * height
    assert all(d < REACH * height for d in residuals(obj).values())  # the feet stay planted
    assert keys_state(obj) == keys
    assert live.status(obj) == ""


def test_applying_the_pose_does_not_solve_again(live):
    obj = live_rig()
    obj.fullbody_adjust.live = True
    count = solves(live, obj)
    move_hand_target(obj)
    bpy.context.view_layer.update()
    assert solves(live, obj) == count + 1
    for _ in range(3):  # the pose Live wrote is evaluated; nothing else moved
        bpy.context.view_layer.update()
        Pose(obj)
    assert solves(live, obj) == count + 1


def test_target_moved_back_brings_the_body_back(live):
    obj = live_rig()
    obj.fullbody_adjust.live = True
    shown = pose_channels(obj)
    target = slot(obj, "hand.L").target
    home = target.matrix_world.translation.copy()
    reach_left_hand(obj, Pose(obj), "trunk")  # the trunk must bend
    bpy.context.view_layer.update()
    assert hand_distance(obj) < REACH * Pose(obj).height()
    bent = pose_channels(obj)
    trunk = bone_map(obj)["trunk"]
    assert any(bent[b] != shown[b] for b in trunk)
    place(target, home)
    bpy.context.view_layer.update()
    back = pose_channels(obj)
    for bone in trunk:
        np.testing.assert_allclose(np.concatenate(back[bone][1:]), np.concatenate(shown[bone][1:]), atol=1e-6)


def test_an_update_back_to_a_target_shows_the_pose_shown_there_before(live):
    """Updates from one start pose share the work prepared from it: what an update shows depends on the
    targets only, so a target moved away and back shows exactly the pose of its first visit."""
    obj = live_rig()
    obj.fullbody_adjust.live = True
    target = slot(obj, "hand.L").target
    there = move_hand_target(obj)
    bpy.context.view_layer.update()
    first = pose_channels(obj)
    reach_left_hand(obj, Pose(obj), "trunk")
    bpy.context.view_layer.update()
    assert pose_channels(obj) != first
    place(target, there)
    bpy.context.view_layer.update()
    assert pose_channels(obj) == first


def test_frame_change_solves_the_animated_target(live):
    obj = live_rig()
    target = slot(obj, "hand.L").target
    scene = bpy.context.scene
    scene.frame_set(1)
    target.keyframe_insert("location", frame=1)
    goal = move_hand_target(obj)
    target.keyframe_insert("location", frame=20)
    scene.frame_set(1)
    obj.fullbody_adjust.live = True
    height = Pose(obj).height()
    count = solves(live, obj)

    scene.frame_set(20)
    assert solves(live, obj) == count + 1
    assert np.allclose(np.array(target.matrix_world.translation), goal, atol=1e-6)
    assert hand_distance(obj) < REACH * height
    scene.frame_set(10)  # half way
    assert hand_distance(obj) < REACH * height
    assert not animating_fcurves(obj)  # no keys on the armature


def test_key_pose_keys_the_current_frame_only(live):
    obj = live_rig(keyed=True)
    frame = KEY_FRAME
    keys = keys_state(obj)
    obj.fullbody_adjust.live = True
    move_hand_target(obj)
    bpy.context.view_layer.update()
    shown = pose_channels(obj)

    assert bpy.ops.fullbody_adjust.key_pose() == {'FINISHED'}

    after = keys_state(obj)
    keyed_bones = {key[0].split('"')[1] for key in after if after[key] != keys.get(key)}
    arm = set(bone_map(obj)["arm.L"])
    assert keyed_bones and keyed_bones <= arm | set(bone_map(obj)["hand.L"])
    for path, before in keys.items():
        if path in after and path[0].split('"')[1] in keyed_bones:
            assert (without_derived_handles(drop_frame(after[path], frame))
                    == without_derived_handles(drop_frame(before, frame))), path
        else:
            assert after[path] == before, path
    curves = {(fc.data_path, fc.array_index): fc for fc in animating_fcurves(obj)}
    for (path, index), fcurve in curves.items():
        bone = path.split('"')[1]
        if bone in keyed_bones and ".rotation" in path:
            at = keys_at(fcurve, frame)
            assert len(at) == 1
            value = fcurve.keyframe_points[int(at[0])].co[1]
            prop = path.rsplit(".", 1)[1]
            assert value == pytest.approx(getattr(obj.pose.bones[bone], prop)[index], abs=1e-6)
    assert live.state_of(obj).written == ()

    # The keys give back what Live showed.
    bpy.context.scene.frame_set(1)
    bpy.context.scene.frame_set(frame)
    again = pose_channels(obj)
    for bone in keyed_bones:
        np.testing.assert_allclose(np.concatenate(again[bone][1:]), np.concatenate(shown[bone][1:]), atol=1e-6)


def test_live_off_returns_to_the_keyed_pose(live):
    obj = live_rig(keyed=True)
    before = pose_channels(obj)
    before_pose = Pose(obj)
    obj.fullbody_adjust.live = True
    reach_left_hand(obj, before_pose, "trunk")
    bpy.context.view_layer.update()
    assert pose_channels(obj) != before

    obj.fullbody_adjust.live = False
    assert pose_channels(obj) == before
    np.testing.assert_allclose(Pose(obj).matrices, before_pose.matrices, atol=1e-6)
    assert live.state_of(obj) is None


def test_live_off_costs_nothing_and_changes_nothing(live):
    obj = live_rig()
    before = pose_channels(obj)
    move_hand_target(obj)
    bpy.context.view_layer.update()
    bpy.context.scene.frame_set(3)
    assert pose_channels(obj) == before
    assert live.state_of(obj) is None
    assert not live._states


def test_deleted_target_is_left_out(live):
    obj = live_rig()
    obj.fullbody_adjust.live = True
    height = Pose(obj).height()
    bpy.data.objects.remove(slot(obj, "hand.R").target)
    bpy.context.view_layer.update()
    goal = move_hand_target(obj)
    bpy.context.view_layer.update()  # must not raise
    assert "hand.R" in live.status(obj) and "missing" in live.status(obj)
    assert hand_distance(obj) < REACH * height
    assert np.allclose(np.array(slot(obj, "hand.L").target.matrix_world.translation), goal)


def test_armature_moved_solves_again(live):
    obj = live_rig()
    obj.fullbody_adjust.live = True
    height = Pose(obj).height()
    move_hand_target(obj)
    bpy.context.view_layer.update()
    count = solves(live, obj)
    obj.location.x += 0.05 * height  # the targets stay where they are in the world
    bpy.context.view_layer.update()
    assert solves(live, obj) == count + 1
    assert hand_distance(obj) < REACH * height


def test_found_again_after_reloading_the_file(live, tmp_path):
    obj = live_rig()
    obj.fullbody_adjust.live = True
    path = tmp_path / "live.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    assert not live._states
    bpy.ops.wm.open_mainfile(filepath=str(path))
    obj = bpy.data.objects["metarig"]
    assert obj.fullbody_adjust.live and live.state_of(obj) is not None
    move_hand_target(obj)
    bpy.context.view_layer.update()
    assert hand_distance(obj) < REACH * Pose(obj).height()


def test_handler_works_after_undo(live):
    obj = live_rig()
    obj.fullbody_adjust.live = True
    bpy.ops.ed.undo_push(message="live on")
    target = slot(obj, "hand.L").target
    target.location.z += 0.01
    bpy.ops.ed.undo_push(message="moved")
    bpy.ops.ed.undo()
    obj = bpy.data.objects["metarig"]  # Undo replaced the objects
    assert live.state_of(obj) is not None
    move_hand_target(obj)
    bpy.context.view_layer.update()
    assert hand_distance(obj) < REACH * Pose(obj).height()


def test_frame_change_solves_from_that_frames_animation(live):
    obj = live_rig(keyed=True)
    scene = bpy.context.scene
    scene.frame_set(1)
    animated_at_1 = pose_channels(obj)
    scene.frame_set(KEY_FRAME)
    obj.fullbody_adjust.live = True
    move_hand_target(obj)
    bpy.context.view_layer.update()
    height = Pose(obj).height()

    scene.frame_set(1)
    assert hand_distance(obj) < REACH * height
    obj.fullbody_adjust.live = False
    assert pose_channels(obj) == animated_at_1


def test_panel_shows_the_toggle_and_key_pose_while_live(live):
    from .test_extension import draw_panel

    obj = live_rig()
    layout = draw_panel("FULLBODY_ADJUST_PT_main", obj)
    assert (obj.fullbody_adjust, "live") in layout.all_props()
    assert "fullbody_adjust.key_pose" not in layout.all_operators()
    assert not bpy.ops.fullbody_adjust.key_pose.poll()

    obj.fullbody_adjust.live = True
    layout = draw_panel("FULLBODY_ADJUST_PT_main", obj)
    assert "fullbody_adjust.key_pose" in layout.all_operators()
    assert bpy.ops.fullbody_adjust.key_pose.poll()
    assert not [text for text in layout.all_labels() if "missing" in text]
    bpy.data.objects.remove(slot(obj, "foot.R").target)
    bpy.context.view_layer.update()
    move_hand_target(obj)
    bpy.context.view_layer.update()
    problems = [text for text in draw_panel("FULLBODY_ADJUST_PT_main", obj).all_labels() if "missing" in text]
    assert len(problems) == 1 and "foot.R" in problems[0]


def test_live_on_an_armature_without_targets_reports_once(live):
    obj = add_rig("basic")
    obj.fullbody_adjust.live = True  # no targets yet: nothing to solve, no exception
    assert "target" in live.status(obj).lower()
    assert bpy.ops.fullbody_adjust.key_pose.poll()
    with pytest.raises(RuntimeError, match="Nothing to key"):
        bpy.ops.fullbody_adjust.key_pose()


def test_key_pose_with_a_deleted_target_keys_the_rest(live):
    obj = live_rig()
    obj.fullbody_adjust.live = True
    bpy.data.objects.remove(slot(obj, "hand.R").target)
    move_hand_target(obj)
    bpy.context.view_layer.update()
    assert "missing" in live.status(obj)
    assert bpy.ops.fullbody_adjust.key_pose() == {'FINISHED'}
    keyed = {fc.data_path.split('"')[1] for fc in animating_fcurves(obj)}
    assert bone_map(obj)["arm.L"][-1] in keyed


def test_renamed_armature_stays_live_and_keeps_its_base_pose(live):
    obj = live_rig()
    before = pose_channels(obj)
    obj.fullbody_adjust.live = True
    move_hand_target(obj)
    bpy.context.view_layer.update()  # Live shows a solved pose...
    obj.name = "Hero"  # ... when the armature is renamed
    slot(obj, "hand.L").target.location.z += 0.01
    bpy.context.view_layer.update()
    assert live.state_of(obj) is not None
    assert hand_distance(obj) < REACH * Pose(obj).height()
    assert pose_channels(obj) != before
    obj.fullbody_adjust.live = False  # back to the pose from before Live, not the one it showed
    assert pose_channels(obj) == before


def test_adjust_frames_steps_frames_without_live_solving_each(live):
    obj = live_after_a_target_move(keyed=True)
    count = solves(live, obj)
    assert bpy.ops.fullbody_adjust.adjust_frames(frame_start=1, frame_end=10) == {'FINISHED'}
    assert solves(live, obj) == count + 1  # once, back on the current frame
    assert bpy.context.scene.frame_current == KEY_FRAME
    assert hand_distance(obj) < REACH * Pose(obj).height()


def test_key_pose_is_undone_by_undo(live):
    obj = live_after_a_target_move(keyed=True)
    keys = keys_state(obj)
    bpy.ops.ed.undo_push(message="before keying")
    assert bpy.ops.fullbody_adjust.key_pose('EXEC_DEFAULT', True) == {'FINISHED'}
    assert keys_state(obj) != keys
    bpy.ops.ed.undo()
    obj = bpy.data.objects["metarig"]
    assert keys_state(obj) == keys


def test_an_edited_rig_is_read_again_before_the_next_solve(live):
    """Editing the armature while Live is on (here: a longer forearm) changes the rest pose the shown pose is
    computed from: the next solve reads the rig again, so the hand still lands on its target."""
    obj = live_after_a_target_move()
    height = Pose(obj).height()
    assert hand_distance(obj) < REACH * height
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    forearm = obj.data.edit_bones["forearm.L"]
    forearm.tail = forearm.head + 1.2 * (forearm.tail - forearm.head)  # the hand is connected: it moves too
    bpy.ops.object.mode_set(mode='OBJECT')
    bpy.context.view_layer.update()
    move_hand_target(obj)  # the same spot again, as a drag that goes on
    target = slot(obj, "hand.L").target
    target.location = target.location + target.location.orthogonal().normalized() * 0.02 * height
    bpy.context.view_layer.update()
    assert hand_distance(obj) < REACH * height


def test_moving_a_pole_solves_again(live):
    """The elbow follows its pole while the pole is dragged, as it follows the hand's target: each pole move
    solves, and the pose shown is the one Adjust Pose gives for the same targets and pole."""
    obj = live_after_a_target_move()
    pose = Pose(obj)
    height = pose.height()
    up, _left, forward = body_axes(obj, pose)
    joints = chain_joints(obj, pose, "arm.L")
    middle = joints[-3] + 0.5 * (joints[-1] - joints[-3])
    pole = bpy.data.objects.new("Pole", None)
    bpy.context.scene.collection.objects.link(pole)
    slot(obj, "hand.L").pole = pole
    bpy.context.view_layer.update()
    solved = solves(live, obj)
    elbows = []
    for side in (-up, -forward):  # below the arm, then behind it
        place(pole, pose.to_world(middle + 0.6 * chain_length(joints) * side))
        bpy.context.view_layer.update()
        elbows.append(chain_joints(obj, Pose(obj), "arm.L")[-2])
        assert hand_distance(obj) < REACH * height
    assert solves(live, obj) == solved + 2
    assert live.status(obj) == ""
    assert np.linalg.norm(elbows[1] - elbows[0]) > 0.02 * height  # the elbow went with the pole

    obj.fullbody_adjust.live = False  # back to the base pose, solved by Adjust Pose from there
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    np.testing.assert_allclose(chain_joints(obj, Pose(obj), "arm.L")[-2], elbows[1], atol=1e-5 * height)


def test_moving_an_obstacle_into_the_arm_solves_again(live):
    """An obstacle dragged onto the elbow pushes the arm out of it while the hand stays on its target; moving
    a mesh that is no obstacle (it rides on the armature) does not solve."""
    obj = live_after_a_target_move()
    height = Pose(obj).height()
    elbow = chain_joints(obj, Pose(obj), "arm.L")[-2]
    box = add_box(obj, (100.0, 100.0, 100.0), 0.12 * height)
    bpy.context.view_layer.update()
    solved = solves(live, obj)
    box.location = tuple(Pose(obj).to_world(elbow))
    bpy.context.view_layer.update()
    assert solves(live, obj) == solved + 1
    after = chain_joints(obj, Pose(obj), "arm.L")
    assert not inside_box(box, Pose(obj).to_world(after)).any()
    assert hand_distance(obj) < REACH * height

    rider = add_box(obj, (50.0, 50.0, 50.0), 0.01 * height)
    rider.parent = obj
    bpy.context.view_layer.update()
    solved = solves(live, obj)
    rider.location = (49.0, 50.0, 50.0)
    bpy.context.view_layer.update()
    assert solves(live, obj) == solved


def test_a_changed_setting_solves_once_on_the_next_update(live):
    """Switching the hand's slot off shows the pose without it (the arm back where the base pose has it);
    several settings changed before one update solve once; switching it on solves it again."""
    obj = live_rig()
    base = chain_joints(obj, Pose(obj), "arm.L")
    obj.fullbody_adjust.live = True
    move_hand_target(obj)
    bpy.context.view_layer.update()
    height = Pose(obj).height()
    assert hand_distance(obj) < REACH * height
    solved = solves(live, obj)
    slot(obj, "hand.L").enabled = False
    slot(obj, "foot.R").priority = 5
    obj.fullbody_adjust.margin = 0.02
    bpy.context.view_layer.update()
    assert solves(live, obj) == solved + 1
    np.testing.assert_allclose(chain_joints(obj, Pose(obj), "arm.L"), base, atol=1e-6 * height)
    slot(obj, "hand.L").enabled = True
    bpy.context.view_layer.update()
    assert solves(live, obj) == solved + 2
    assert hand_distance(obj) < REACH * height


def test_obstacles_are_read_again_when_the_scene_changes(live):
    """Live keeps the obstacles' boxes between updates: a box linked where the elbow is counts from the next
    solve on, one hidden stops counting, and editing a box's mesh solves again at once."""
    obj = live_after_a_target_move()
    height = Pose(obj).height()
    free = chain_joints(obj, Pose(obj), "arm.L")
    box = add_box(obj, Pose(obj).to_world(free[-2]), 0.12 * height)  # linked: no solve yet
    bpy.context.view_layer.update()
    assert inside_box(box, Pose(obj).to_world(free[-2:-1])).all()

    target = slot(obj, "hand.L").target
    goal = np.array(target.location)
    target.location = tuple(goal + [0.0, 0.0, 1e-3 * height])  # a drag goes on
    bpy.context.view_layer.update()
    assert not inside_box(box, Pose(obj).to_world(chain_joints(obj, Pose(obj), "arm.L"))).any()
    assert hand_distance(obj) < REACH * height

    solved = solves(live, obj)
    for vertex in box.data.vertices:  # the box grows: its mesh changed, the pose follows at once
        vertex.co = vertex.co * 1.5
    box.data.update()
    bpy.context.view_layer.update()
    assert solves(live, obj) == solved + 1
    assert not inside_box(box, Pose(obj).to_world(chain_joints(obj, Pose(obj), "arm.L"))).any()

    box.hide_set(True)  # hidden: no obstacle from the next solve on
    bpy.context.view_layer.update()
    target.location = tuple(goal)
    bpy.context.view_layer.update()
    np.testing.assert_allclose(chain_joints(obj, Pose(obj), "arm.L"), free, atol=1e-6 * height)


def test_an_obstacle_edit_that_keeps_its_box_does_not_solve(live):
    """A mesh edit that leaves the mesh's box where it was (a triangulated cube) solves nothing; one that moves the
    box does. So a mesh that follows the pose some other way (a driver) stops Live solving once its box is still."""
    obj = live_after_a_target_move()
    height = Pose(obj).height()
    box = add_box(obj, (0.3 * height, -0.5 * height, 0.5 * height), 0.1 * height)
    bpy.context.view_layer.update()
    move_hand_target(obj)  # a solve that reads the box
    target = slot(obj, "hand.L").target
    target.location = tuple(np.array(target.location) + [0.0, 0.0, 1e-3 * height])
    bpy.context.view_layer.update()
    solved = solves(live, obj)
    box.modifiers.new("triangles", 'TRIANGULATE')  # the mesh changed, its box did not
    bpy.context.view_layer.update()
    assert solves(live, obj) == solved
    box.location = tuple(np.array(box.location) + [0.0, 0.0, 0.01 * height])
    bpy.context.view_layer.update()
    assert solves(live, obj) == solved + 1
