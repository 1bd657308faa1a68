"""Retargeting through the bpy wheel (bridge/retarget.py and the fullbody_adjust.retarget operator).

A CMU clip imported with Blender's own BVH importer is the source; targets are the Rigify basic metarig
(another skeleton, A-pose, its object scaled) and a copy of the BVH armature with its bones scaled in Edit
Mode. Every check evaluates the result in Blender (frame_set) and compares it with numbers computed here from
the source's own evaluated motion: the wrists and ankles reach the planned targets, planted feet stay
still, the motion is as smooth as the source's, the source's action is unchanged bit for bit, and the new
action holds the keys."""


import bpy
import numpy as np
import pytest

from fullbody_adjust.bridge import mapping, retarget
from fullbody_adjust.bridge.errors import AdjustError
from fullbody_adjust.bridge.pose import read_pose_frames
from fullbody_adjust.solver import retarget as rt
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR

from .test_keyframes import assert_same_curve, fcurves_of

WALK = "cmu_07_01_walk.bvh"
CLIMB = "cmu_01_06_climb_sit_f360-1559.bvh"
FRAMES = (2, 151)  # frame 1 is the conversion's T-pose


def enable_addon(module):
    if module not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module=module)


def import_clip(name=WALK):
    enable_addon("io_anim_bvh")
    bpy.ops.import_anim.bvh(filepath=str(MOCAP_DIR / name), global_scale=CMU_SCALE, update_scene_fps=True,
                            update_scene_duration=True)
    return bpy.context.active_object


def add_metarig(scale=1.2, location=(1.5, 0.0, 0.0)):
    enable_addon("rigify")
    bpy.ops.object.armature_basic_human_metarig_add()
    rig = bpy.context.active_object
    rig.scale = (scale,) * 3
    rig.location = location
    bpy.context.view_layer.update()
    return rig


def scaled_copy(source, scale):
    """A copy of the BVH armature (its own armature data, no animation) with every bone scaled in Edit Mode."""
    rig = source.copy()
    rig.data = source.data.copy()
    rig.animation_data_clear()
    rig.name = "Scaled"
    bpy.context.scene.collection.objects.link(rig)
    select_only(rig)
    bpy.ops.object.mode_set(mode='EDIT')
    bones = rig.data.edit_bones
    # All from the original positions first: moving a connected bone's head moves its parent's tail too.
    rest = {b.name: (b.head * scale, b.tail * scale) for b in bones}
    for bone in bones:
        bone.head, bone.tail = rest[bone.name]
    bpy.ops.object.mode_set(mode='OBJECT')
    return rig


def select_only(*objects, active=None):
    for ob in bpy.context.view_layer.objects:
        ob.select_set(False)
    for ob in objects:
        ob.select_set(True)
    bpy.context.view_layer.objects.active = active or objects[-1]


def evaluated_heads(obj, frames):
    """World bone heads (F,J,3) of ``obj`` at ``frames``, evaluated by Blender."""
    return read_pose_frames(obj, np.asarray(frames, dtype=float)).heads


def evaluated_tails(obj, frames):
    return read_pose_frames(obj, np.asarray(frames, dtype=float)).tails


def bone_indices(obj, bones):
    names = [b.name for b in obj.data.bones]
    return [names.index(b) for b in bones]


def effector_bones(obj):
    stored = mapping.load_map(obj) or mapping.map_rig(mapping.describe_armature(obj))
    return [stored.bones(e)[-1] for e in rt.EFFECTORS]


def source_fcurves(source):
    return fcurves_of(source, source.animation_data.action)


def assert_unchanged(source, before, action):
    assert source.animation_data.action == action
    after = source_fcurves(source)
    assert after.keys() == before.keys()
    for key in before:
        assert_same_curve(after[key], before[key])


def frames_of(outcome):
    return outcome.frames.astype(int)


# ---------------------------------------------------------------------------------------------------------
# Reading the source


def test_the_f_curves_give_the_pose_blender_evaluates():
    source = import_clip()
    frames = np.arange(2, 60, 3, dtype=float)
    rig = retarget._rig(source, retarget._source_map(source))
    fast, world, how = retarget.read_motion(source, rig, frames)
    assert how == "F-Curves"
    evaluated = read_pose_frames(source, frames)
    np.testing.assert_allclose(fast, evaluated.pose_matrices, atol=2e-5)
    np.testing.assert_allclose(world, evaluated.matrix_world[0], atol=1e-7)


def test_a_constrained_source_is_read_frame_by_frame():
    source = import_clip()
    constraint = source.pose.bones["LeftForeArm"].constraints.new('LIMIT_ROTATION')
    constraint.use_limit_x = True
    constraint.owner_space = 'LOCAL'
    rig = retarget._rig(source, retarget._source_map(source))
    frames = np.arange(2, 30, 3, dtype=float)
    pose, _world, how = retarget.read_motion(source, rig, frames)
    assert how == "frame by frame"
    np.testing.assert_allclose(pose, read_pose_frames(source, frames).pose_matrices, atol=1e-6)


# ---------------------------------------------------------------------------------------------------------
# The function the command line calls


def test_retarget_onto_another_skeleton_reaches_holds_and_leaves_the_source_alone():
    source = import_clip()
    action = source.animation_data.action
    before = source_fcurves(source)
    target = add_metarig(1.2)
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES)

    # A new action on the target, keyed on every frame; the source untouched.
    assert outcome.action is target.animation_data.action
    assert outcome.action.name == f"{action.name}_{target.name}" and outcome.action != action
    curves = fcurves_of(target)
    keyed_bones = {path.split('"')[1] for path, _ in curves}
    assert keyed_bones == set(outcome.keyed_bones)
    assert all(len(c["co"]) == FRAMES[1] - FRAMES[0] + 1 for c in curves.values())
    assert_unchanged(source, before, action)

    # Evaluated by Blender, the wrists and ankles are on the planned targets.
    frames = frames_of(outcome)
    heads = evaluated_heads(target, frames)[:, bone_indices(target, effector_bones(target))]
    reach = np.linalg.norm(heads - outcome.targets, axis=-1)
    size = rt.leg_length(retarget._rig(target, mapping.load_map(target)))
    assert np.percentile(reach, 99) < 1e-4 * size and reach.max() < 1e-3 * size

    # Planted feet do not slide: each held interval keeps the ankle where it is.
    for k, effector in enumerate(rt.EFFECTORS):
        held = outcome.contacts[:, k]
        if effector.startswith("foot"):
            assert held.sum() > 0.2 * len(frames), effector  # a walk: each foot planted a good part of the time
        runs = rt.intervals(held)
        for a, b in runs:
            assert np.ptp(heads[a:b, k], axis=0).max() < 2e-4 * size


def test_retargeted_motion_is_as_smooth_as_the_source():
    """No new pops: the largest frame-to-frame change of velocity of any mapped joint, relative to the leg
    length, at most 1.5 times the source's (both evaluated by Blender)."""
    source = import_clip()
    target = add_metarig(0.85)
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES)
    frames = frames_of(outcome)
    roughness = []
    for rig in (source, target):
        bone_map = mapping.load_map(rig) or mapping.map_rig(mapping.describe_armature(rig))
        bones = [b for _, b in bone_map.items()]
        heads = evaluated_heads(rig, frames)[:, bone_indices(rig, bones)]
        roughness.append(rt.roughness(heads, rt.leg_length(retarget._rig(rig, bone_map))).max())
    assert roughness[1] <= 1.5 * roughness[0]


def test_a_scaled_copy_of_the_source_follows_it_scaled():
    """Same skeleton, bones scaled 0.85 in Edit Mode: the target's hands follow the source's exactly, scaled
    by 0.85 about the ground below the hips, and its head turns exactly as the source's."""
    source = import_clip()
    target = scaled_copy(source, 0.85)
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES, new_action="scaled walk")
    assert outcome.action.name == "scaled walk"
    assert outcome.leg_ratio == pytest.approx(0.85, rel=1e-5)
    frames = frames_of(outcome)
    s_heads = evaluated_heads(source, frames)
    t_heads = evaluated_heads(target, frames)
    s_rig = retarget._rig(source, retarget._source_map(source))
    hips = [s_rig.groups["leg.L"][0], s_rig.groups["leg.R"][0]]
    s_anchor = s_rig.rest[hips, :3, 3].mean(axis=0)
    t_anchor = 0.85 * s_anchor
    s_anchor[2] = t_anchor[2] = np.percentile(rt.sole_heights(s_rig, s_heads, evaluated_tails(source, frames)), 2)
    hands = bone_indices(source, ["LeftHand", "RightHand"])
    np.testing.assert_allclose(t_heads[:, hands], t_anchor + 0.85 * (s_heads[:, hands] - s_anchor), atol=2e-5)
    head = bone_indices(source, ["Head"])[0]
    s_rot = read_pose_frames(source, frames).matrices[:, head, :3, :3]
    t_rot = read_pose_frames(target, frames).matrices[:, head, :3, :3]
    np.testing.assert_allclose(t_rot, s_rot, atol=2e-5)


def test_exact_ground_contacts_put_the_soles_on_the_ground():
    source = import_clip()
    loose_target = add_metarig(1.2, location=(1.5, 0.0, 0.0))
    exact_target = add_metarig(1.2, location=(-1.5, 0.0, 0.0))
    loose = retarget.retarget(bpy.context, source, loose_target, *FRAMES)
    exact = retarget.retarget(bpy.context, source, exact_target, *FRAMES, exact=True)
    frames = frames_of(exact)
    ground = np.percentile(rt.sole_heights(retarget._rig(source, retarget._source_map(source)),
                                           evaluated_heads(source, frames), evaluated_tails(source, frames)), 2)
    gaps = {}
    for name, rig, outcome in (("loose", loose_target, loose), ("exact", exact_target, exact)):
        feet = mapping.load_map(rig)
        soles = []
        for k, effector in enumerate(rt.EFFECTORS[2:], start=2):
            below = bone_indices(rig, [b.name for b in rig.data.bones[feet.bones(effector)[0]].children_recursive]
                                 + [feet.bones(effector)[0]])
            held = outcome.contacts[:, k]
            points = np.concatenate([evaluated_heads(rig, frames)[:, below], evaluated_tails(rig, frames)[:, below]],
                                    axis=1)
            soles.append(points[held, :, 2].min(axis=1))
        gaps[name] = np.abs(np.concatenate(soles) - ground)
    # Exact: the metarig's soles (its heel and toe joints) stand on the ground; scaled: they do not.
    assert np.median(gaps["exact"]) < 0.01
    assert np.median(gaps["loose"]) > 2 * np.median(gaps["exact"])


def test_exact_object_contacts_hold_the_hands_where_the_source_holds_the_bar():
    """Climb: the source's hands rest on a bar. With a box there and exact object contacts, the target's
    wrists go to the source's own world positions on it."""
    source = import_clip(CLIMB)
    frames = np.arange(2, 600, dtype=float)
    wrists = evaluated_heads(source, frames)[:, bone_indices(source, ["LeftHand", "RightHand"])]
    speed = np.linalg.norm(np.gradient(wrists, axis=0), axis=-1) * bpy.context.scene.render.fps
    still = (speed < 0.1).all(axis=1)
    assert still.sum() > 30
    bar_points = wrists[still].reshape(-1, 3)
    bpy.ops.mesh.primitive_cube_add()
    bar = bpy.context.active_object
    bar.name = "Bar"
    bar.location = (bar_points.min(axis=0) + bar_points.max(axis=0)) / 2
    bar.scale = (bar_points.max(axis=0) - bar_points.min(axis=0)) / 2 + 0.02
    target = add_metarig(1.1, location=(0.0, 0.0, 0.0))
    outcome = retarget.retarget(bpy.context, source, target, 2, 599, contacts="object", contact_object="Bar",
                                exact=True)
    t_wrists = evaluated_heads(target, frames)[:, bone_indices(target, effector_bones(target)[:2])]
    checked = 0
    for k in range(2):
        for a, b in rt.intervals(outcome.contacts[:, k]):
            np.testing.assert_allclose(t_wrists[a:b, k], np.broadcast_to(wrists[a:b, k].mean(axis=0), (b - a, 3)),
                                       atol=2e-4)
            checked += b - a
    assert checked > 30


def test_bad_input_is_one_line_and_changes_nothing():
    source = import_clip()
    target = add_metarig()
    actions = set(bpy.data.actions)
    with pytest.raises(AdjustError, match="same armature"):
        retarget.retarget(bpy.context, source, source)
    with pytest.raises(AdjustError, match="empty"):
        retarget.retarget(bpy.context, source, target, 50, 10)
    with pytest.raises(AdjustError, match="contact object"):
        retarget.retarget(bpy.context, source, target, 2, 20, contacts="object", contact_object="Nothing")
    with pytest.raises(AdjustError, match="ground or object"):
        retarget.retarget(bpy.context, source, target, 2, 20, contacts="wall")
    empty = bpy.data.objects.new("Empty", None)
    bpy.context.scene.collection.objects.link(empty)
    with pytest.raises(AdjustError, match="not an armature"):
        retarget.retarget(bpy.context, empty, target, 2, 20)
    target.scale = (1.0, 2.0, 1.0)
    bpy.context.view_layer.update()
    with pytest.raises(AdjustError, match="uniform"):
        retarget.retarget(bpy.context, source, target, 2, 20)
    assert set(bpy.data.actions) == actions
    assert target.animation_data is None or target.animation_data.action is None


# ---------------------------------------------------------------------------------------------------------
# The operator


def test_operator_retargets_the_selected_armature_onto_the_active_one():
    source = import_clip()
    action = source.animation_data.action
    before = source_fcurves(source)
    target = add_metarig(1.2)
    select_only(source, target, active=target)
    assert bpy.ops.fullbody_adjust.retarget(frame_start=2, frame_end=61) == {'FINISHED'}
    new = target.animation_data.action
    assert new is not None and new != action
    assert all(len(c["co"]) == 60 for c in fcurves_of(target).values())
    assert_unchanged(source, before, action)

    # Again by name, into a named action: the first stays as it was.
    first_keys = fcurves_of(target)
    select_only(target)
    assert bpy.ops.fullbody_adjust.retarget(source=source.name, frame_start=2, frame_end=31, exact=True,
                                            new_action="exact") == {'FINISHED'}
    assert target.animation_data.action.name == "exact"
    assert all(len(c["co"]) == 30 for c in fcurves_of(target).values())
    kept = fcurves_of(target, new)
    for key in first_keys:
        assert_same_curve(kept[key], first_keys[key])
    assert_unchanged(source, before, action)


def test_operator_reports_what_is_missing():
    source = import_clip()
    target = add_metarig()
    select_only(target)
    with pytest.raises(RuntimeError, match="Select the source armature"):
        bpy.ops.fullbody_adjust.retarget()
    select_only(source, target, active=target)
    with pytest.raises(RuntimeError, match="contact object"):
        bpy.ops.fullbody_adjust.retarget(contacts='OBJECT')
    assert target.animation_data is None or target.animation_data.action is None
    select_only(source)
    bpy.context.view_layer.objects.active = None
    assert not bpy.ops.fullbody_adjust.retarget.poll()
