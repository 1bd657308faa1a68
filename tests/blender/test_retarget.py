"""Retargeting through the bpy wheel (bridge/retarget/run.py and the fullbody_adjust.retarget operator).

A CMU clip imported with Blender's own BVH importer is the source; targets are the Rigify basic metarig
(another skeleton, A-pose, its object scaled) and a copy of the BVH armature with its bones scaled in Edit
Mode. Every check evaluates the result in Blender (frame_set) and compares it with numbers computed here from
the source's own evaluated motion: the wrists and ankles reach the planned targets, planted feet stay
still, the motion is as smooth as the source's, the source's action is unchanged bit for bit, and the new
action holds the keys."""


import bpy
import numpy as np
import pytest

from fullbody_adjust.bridge.writing import keyframes
from fullbody_adjust.bridge.rig import mapping
from fullbody_adjust.bridge.retarget import run as retarget
from fullbody_adjust.bridge.errors import AdjustError
from fullbody_adjust.bridge.reading.pose import read_pose_frames
from fullbody_adjust.bridge.retarget.read import read_motion, rig_of, source_map
from fullbody_adjust.solver.retarget import motion as rt
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR
from tests.helpers.climb_bar import add_bar

from .test_keyframes import assert_same_curve, fcurves_of

WALK = "cmu_07_01_walk.bvh"
CLIMB = "cmu_01_06_climb_sit_f360-1559.bvh"
FRAMES = (2, 151)  # frame 1 is the conversion's T-pose


def enable_addon(module):
    if module not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module=module)


def import_clip(name=WALK, fps=None, speed=1.0):
    """The clip imported with Blender's BVH importer: at its own 120 fps, or with its keys scaled to ``fps``
    (as a user whose scene runs at 30 fps gets it), then played ``speed`` times as fast."""
    enable_addon("io_anim_bvh")
    if fps is not None:
        bpy.context.scene.render.fps = fps
    bpy.ops.import_anim.bvh(filepath=str(MOCAP_DIR / name), global_scale=CMU_SCALE, update_scene_fps=fps is None,
                            update_scene_duration=True, use_fps_scale=fps is not None)
    bpy.context.scene.render.fps = int(round(bpy.context.scene.render.fps * speed))
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


def foot_points(rig, frames, effector):
    """World heads and tails (F,P,3) of the foot bone of ``effector`` and every bone below it (toes, heel),
    evaluated by Blender."""
    foot = rig.data.bones[mapping.load_map(rig).bones(effector)[0]]
    bones = bone_indices(rig, [foot.name] + [b.name for b in foot.children_recursive])
    snapshot = read_pose_frames(rig, np.asarray(frames, dtype=float))
    return np.concatenate([snapshot.heads[:, bones], snapshot.tails[:, bones]], axis=1)


def source_foot_points(source, frames, effector):
    """foot_points of the source (its bone map read, not stored)."""
    foot = source.data.bones[source_map(source).bones(effector)[0]]
    bones = bone_indices(source, [foot.name] + [b.name for b in foot.children_recursive])
    snapshot = read_pose_frames(source, np.asarray(frames, dtype=float))
    return np.concatenate([snapshot.heads[:, bones], snapshot.tails[:, bones]], axis=1)


def fcurves_of_object(obj):
    """The object's own (not its bones') F-Curves in its action, on every Blender's action layout."""
    return [fc for fc in keyframes.animating_fcurves(obj) if not fc.data_path.startswith("pose.")]


def contacts_of(outcome, effector, kind=None):
    """[(start, stop)] of the source's contacts the outcome reports for ``effector`` (of one kind)."""
    return [(c["start"], c["stop"]) for c in outcome.contact_report["effectors"][effector]["contacts"]
            if kind is None or c["kind"] == kind]


def slides(points, runs):
    """Per contact, how far the foot's stillest point (the one it turns about) moves horizontally from one
    frame to the next, summed over the contact (points (F,P,3))."""
    return np.array([np.linalg.norm(np.diff(points[a:b, :, :2], axis=0), axis=-1).min(axis=1).sum()
                     for a, b in runs])


def source_floor(source, frames):
    """The floor under the source: the 2nd percentile of its lowest foot points (heads and tails of the feet's
    bones: the BVH's end sites are real), evaluated by Blender."""
    lowest = np.minimum(*(source_foot_points(source, frames, e)[..., 2].min(axis=1) for e in ("foot.L", "foot.R")))
    return np.percentile(lowest, 2)


# ---------------------------------------------------------------------------------------------------------
# Reading the source


def test_the_f_curves_give_the_pose_blender_evaluates():
    source = import_clip()
    frames = np.arange(2, 60, 3, dtype=float)
    rig = rig_of(source, source_map(source))
    fast, world, how = read_motion(source, rig, frames)
    assert how == "F-Curves"
    evaluated = read_pose_frames(source, frames)
    np.testing.assert_allclose(fast, evaluated.pose_matrices, atol=2e-5)
    np.testing.assert_allclose(world, evaluated.matrix_world[0], atol=1e-7)


def test_a_constrained_source_is_read_frame_by_frame():
    source = import_clip()
    constraint = source.pose.bones["LeftForeArm"].constraints.new('LIMIT_ROTATION')
    constraint.use_limit_x = True
    constraint.owner_space = 'LOCAL'
    rig = rig_of(source, source_map(source))
    frames = np.arange(2, 30, 3, dtype=float)
    pose, _world, how = read_motion(source, rig, frames)
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
    size = rt.leg_length(rig_of(target, mapping.load_map(target)))
    assert np.percentile(reach, 99) < 1e-4 * size and reach.max() < 1e-3 * size

    # Planted feet do not slide: the point each turns about (heel, ball, toes) stays where it is.
    for k, effector in enumerate(rt.EFFECTORS[2:], start=2):
        assert outcome.contacts[:, k].sum() > 0.2 * len(frames), effector  # a walk: planted a good part of the time
        assert slides(foot_points(target, frames, effector), contacts_of(outcome, effector)).max() < 1e-3 * size
    assert not outcome.contacts[:, :2].any()


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
        roughness.append(rt.roughness(heads, rt.leg_length(rig_of(rig, bone_map))).max())
    assert roughness[1] <= 1.5 * roughness[0]


def test_a_scaled_copy_of_the_source_follows_it_scaled():
    """Same skeleton, bones scaled 0.85 in Edit Mode: relative to its hips, the target's hands follow the
    source's exactly, scaled by 0.85, and its head turns exactly as the source's (the body as a whole moves
    only as far as its planted soles had to, onto the floor)."""
    source = import_clip()
    target = scaled_copy(source, 0.85)
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES, new_action="scaled walk")
    assert outcome.action.name == "scaled walk"
    assert outcome.leg_ratio == pytest.approx(0.85, rel=1e-5)
    frames = frames_of(outcome)
    s_heads = evaluated_heads(source, frames)
    t_heads = evaluated_heads(target, frames)
    hips = bone_indices(source, ["LeftUpLeg", "RightUpLeg"])
    hands = bone_indices(source, ["LeftHand", "RightHand"])
    s_hips, t_hips = s_heads[:, hips].mean(axis=1, keepdims=True), t_heads[:, hips].mean(axis=1, keepdims=True)
    np.testing.assert_allclose(t_heads[:, hands] - t_hips, 0.85 * (s_heads[:, hands] - s_hips), atol=2e-5)
    head = bone_indices(source, ["Head"])[0]
    s_rot = read_pose_frames(source, frames).matrices[:, head, :3, :3]
    t_rot = read_pose_frames(target, frames).matrices[:, head, :3, :3]
    np.testing.assert_allclose(t_rot, s_rot, atol=2e-5)


@pytest.mark.parametrize("fps, speed, scale", [(None, 1.0, 1.2), (None, 1.0, 0.85), (30, 3.0, 1.2)])
def test_soles_rest_on_the_floor_never_below_it_and_do_not_slide(fps, speed, scale):
    """The walk, and the walk imported at 30 fps and played three times as fast (a run's pace: short
    stances, few frames each), onto the metarig 1.2 and 0.85 times its size: no sole below the floor,
    planted soles within 5 mm of it, sliding p95 under 5 mm; the report says the same as measured here
    from Blender's evaluation."""
    source = import_clip(WALK, fps, speed)
    target = add_metarig(scale)
    outcome = retarget.retarget(bpy.context, source, target, *((None, None) if fps else FRAMES))
    frames = frames_of(outcome)
    floor = source_floor(source, frames)
    size = rt.leg_length(rig_of(target, mapping.load_map(target)))
    figures = outcome.contact_report["effectors"]
    assert outcome.contact_report["floor"] == pytest.approx(floor, abs=1e-5)
    planted = 0
    for effector in ("foot.L", "foot.R"):
        points = foot_points(target, frames, effector)
        lowest = points[..., 2].min(axis=1)
        assert lowest.min() > floor - 1e-3
        runs = contacts_of(outcome, effector, "ground")
        assert runs, effector
        on = np.concatenate([lowest[a:b] for a, b in runs])
        assert np.abs(on - floor).max() < 5e-3
        slid = slides(points, runs)
        assert np.percentile(slid, 95) < 5e-3
        planted += len(on)
        # The report's figures agree with these.
        reported = figures[effector]
        errors = np.concatenate([np.abs(points[a:b, :, 2].min(axis=1) - floor) for a, b in
                                 contacts_of(outcome, effector)])
        assert reported["contact_error"]["max"] == pytest.approx(errors.max(), abs=1e-4)
        assert reported["sliding"]["p95"] == pytest.approx(np.percentile(slides(points, contacts_of(outcome, effector)),
                                                                          95), abs=1e-4)
        assert reported["frames_below_floor"] == int(np.sum(lowest < floor - 0.002 * size))
    assert planted > 0.3 * len(frames)


@pytest.mark.parametrize("scale", [1.2, 0.85])
def test_hands_on_a_bar_hold_it_on_a_character_of_any_size(scale):
    """Climb, imported at 30 fps: the source hangs from a bar (a box built here around where its wrists
    rest). Onto the metarig 1.2 and 0.85 times its size, with the floor and the bar as contacts: while the
    source holds the bar the target's hands are within 5 cm of it, and the report's contact error is the one
    measured here. No wrist or ankle pops into, during or out of the hang: from one frame to the next none
    moves farther than the source's own, scaled by the leg ratio, plus 1.5 leg lengths a second (the
    report counts pops the same way: none)."""
    source = import_clip(CLIMB, fps=30)
    lo, hi = source.animation_data.action.frame_range
    frames = np.arange(int(np.ceil(lo)) + 1, int(hi) + 1, dtype=float)  # the conversion's T-pose left out
    wrists = evaluated_heads(source, frames)[:, bone_indices(source, ["LeftHand", "RightHand"])]
    bar = add_bar(wrists, 30)
    box = np.array(bar.bound_box) @ np.array(bar.matrix_world)[:3, :3].T + np.array(bar.matrix_world)[:3, 3]
    lo, hi = box.min(axis=0), box.max(axis=0)
    target = add_metarig(scale, location=(0.0, 0.0, 0.0))
    outcome = retarget.retarget(bpy.context, source, target, int(frames[0]), int(frames[-1]),
                                contacts=["ground", ("object", "Bar")])
    snapshot = read_pose_frames(target, frames)
    size = rt.leg_length(rig_of(target, mapping.load_map(target)))
    s_ends = evaluated_heads(source, frames)[:, bone_indices(source, effector_bones(source))]
    t_ends = snapshot.heads[:, bone_indices(target, effector_bones(target))]
    steps = np.linalg.norm(np.diff(t_ends, axis=0), axis=-1)
    allowed = outcome.leg_ratio * np.linalg.norm(np.diff(s_ends, axis=0), axis=-1) + 1.5 * size / 30
    assert np.all(steps <= allowed), np.unravel_index(np.argmax(steps - allowed), steps.shape)
    assert sum(f["pops"] for f in outcome.contact_report["effectors"].values()) == 0
    held = 0
    hands = bone_indices(target, effector_bones(target)[:2])
    for k, effector in enumerate(("hand.L", "hand.R")):
        hand = target.data.bones[mapping.load_map(target).bones(effector)[-1]]
        below = bone_indices(target, [b.name for b in hand.children_recursive])
        points = np.concatenate([snapshot.heads[:, hands[k], None], snapshot.tails[:, hands[k], None],
                                 snapshot.heads[:, below], snapshot.tails[:, below]], axis=1)
        distance = np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=-1).min(axis=1)
        runs = contacts_of(outcome, effector, "object")
        assert runs, effector
        on = np.concatenate([distance[a:b] for a, b in runs])
        assert on.max() < 0.05
        held += len(on)
        reported = outcome.contact_report["effectors"][effector]
        assert {c["touches"] for c in reported["contacts"] if c["kind"] == "object"} == {"Bar"}
        assert reported["contacts"][0]["frame_start"] == frames[reported["contacts"][0]["start"]]
        assert reported["contact_error"]["max"] == pytest.approx(on.max(), abs=1e-4)
        assert reported["not_held_frames"] == 0
    assert held > 60
    # The same run holds the feet too: on the floor or on the rungs (raised), never on the bar.
    feet = [c["kind"] for e in ("foot.L", "foot.R") for c in outcome.contact_report["effectors"][e]["contacts"]]
    assert feet and set(feet) <= {"ground", "raised"}


def test_feet_on_a_raised_step_stand_on_it():
    """The walk whose second half is raised 0.25 (its object keyed up a step, as if onto a platform): the
    plants up there are raised contacts; the target's soles rest at the height the source's rest there (its
    own lowest foot points, measured here), within 5 mm, do not slide and never go below the floor."""
    source = import_clip()
    first, last, step = 2, 251, 140
    for frame, height in ((first, 0.0), (step, 0.25)):
        source.location.z = height
        source.keyframe_insert("location", index=2, frame=frame)
    for curve in fcurves_of_object(source):
        for key in curve.keyframe_points:
            key.interpolation = 'CONSTANT'
    target = add_metarig(1.2)
    outcome = retarget.retarget(bpy.context, source, target, first, last)
    frames = frames_of(outcome)
    floor = source_floor(source, frames[:step - first])
    raised = 0
    for effector in ("foot.L", "foot.R"):
        points = foot_points(target, frames, effector)
        assert points[..., 2].min() > floor - 1e-3
        s_points = source_foot_points(source, frames, effector)
        runs = contacts_of(outcome, effector, "raised")
        for a, b in runs:
            # A stance the step splits (the source jumps up mid-stance) may start its raised contact a
            # moment early: by at most the gap a contact bridges.
            assert frames[a] >= step - 0.1 * bpy.context.scene.render.fps
            support = s_points[a:b, :, 2].min(axis=1).mean()
            assert support == pytest.approx(floor + 0.25, abs=0.1)
            assert np.abs(points[a:b, :, 2].min(axis=1) - support).max() < 5e-3
            raised += b - a
        assert np.percentile(slides(points, runs), 95) < 5e-3
        assert all(frames[b - 1] < step for a, b in contacts_of(outcome, effector, "ground"))
    assert raised > 60


def test_bad_input_is_one_line_and_changes_nothing():
    source = import_clip()
    target = add_metarig()
    actions = set(bpy.data.actions)
    with pytest.raises(AdjustError, match="same armature"):
        retarget.retarget(bpy.context, source, source)
    with pytest.raises(AdjustError, match="empty"):
        retarget.retarget(bpy.context, source, target, 50, 10)
    with pytest.raises(AdjustError, match="contact object"):
        retarget.retarget(bpy.context, source, target, 2, 20, contacts=[("object", "Nothing")])
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


def test_a_sources_typed_map_is_used_as_typed_and_its_problem_named():
    """A map the user typed on the source is checked, never swapped for detection's: when it names a bone the
    source lacks, the retarget stops with that one line and changes nothing."""
    source = import_clip()
    target = add_metarig()
    mapping.ensure_map(source)
    item = next(item for item in source.fullbody_adjust.bone_map if item.group == "arm.L")
    bone = item.bone
    item.bone = "NoSuchBone"
    stored = [(i.group, i.bone) for i in source.fullbody_adjust.bone_map]
    with pytest.raises(AdjustError, match=f"typed on '{source.name}' does not fit it: arm.L: no bone 'NoSuchBone'"):
        retarget.retarget(bpy.context, source, target, 2, 20)
    assert [(i.group, i.bone) for i in source.fullbody_adjust.bone_map] == stored
    item.bone = bone
    assert source_map(source).source == "stored"


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


def test_operator_warns_when_a_target_within_reach_is_missed(capfd):
    """Onto a character 1.2x the source whose left hip and knee have every IK axis locked, the left foot cannot
    follow the planted sole: the retarget still finishes, and reports a WARNING naming the foot, its frames and
    its largest miss (as the command line exits 1 for the same result); unlocked, the report is INFO."""
    source = import_clip()
    target = add_metarig(1.2)
    select_only(source, target, active=target)
    capfd.readouterr()
    assert bpy.ops.fullbody_adjust.retarget(frame_start=2, frame_end=61) == {'FINISHED'}
    assert "Warning" not in capfd.readouterr().out

    for name in ("thigh.L", "shin.L"):
        bone = target.pose.bones[name]
        bone.lock_ik_x = bone.lock_ik_y = bone.lock_ik_z = True
    outcome = retarget.retarget(bpy.context, source, target, 2, 61, new_action="locked")
    k = outcome.effectors.index("foot.L")
    missed = ~np.isin(outcome.status[:, k], ("reached", "unreachable"))
    assert missed.any()
    select_only(source, target, active=target)
    assert bpy.ops.fullbody_adjust.retarget(frame_start=2, frame_end=61) == {'FINISHED'}
    out = capfd.readouterr().out
    assert f"Warning: foot.L missed its target within reach on {int(missed.sum())} frames by" in out, out
    reported = float(out.split("within reach on ")[1].split(" by ")[1].split()[0])
    assert reported == pytest.approx(float(outcome.residuals[missed, k].max()), rel=1e-3)


def test_operator_options_are_not_remembered_from_the_last_run():
    # Blender would otherwise start each run with the last run's source, frames and action name, marked as set.
    properties = bpy.ops.fullbody_adjust.retarget.get_rna_type().properties
    options = [p for p in properties if p.identifier != "rna_type"]
    assert {p.identifier for p in options} >= {"source", "frame_start", "frame_end", "contacts", "contact_object",
                                               "exact", "new_action"}
    assert [p.identifier for p in options if not p.is_skip_save] == []


def test_operator_reports_what_is_missing():
    source = import_clip()
    target = add_metarig()
    select_only(target)
    with pytest.raises(RuntimeError, match="Select the source armature"):
        bpy.ops.fullbody_adjust.retarget()
    with pytest.raises(RuntimeError, match="Source: no object named 'Nobody' in scene"):
        bpy.ops.fullbody_adjust.retarget(source="Nobody")
    select_only(source, target, active=target)
    with pytest.raises(RuntimeError, match="contact object"):
        bpy.ops.fullbody_adjust.retarget(contacts={'GROUND', 'OBJECT'})
    assert target.animation_data is None or target.animation_data.action is None
    select_only(source)
    bpy.context.view_layer.objects.active = None
    assert not bpy.ops.fullbody_adjust.retarget.poll()


def test_fingers_both_rigs_name_are_carried_over_and_keyed():
    """A scaled copy of the source: its index fingers and thumbs (named so in both) turn exactly as the
    source's do, evaluated by Blender, and are keyed; a finger bone the names do not tell (the CMU finger
    base) keeps its own pose and gets no key."""
    source = import_clip()
    target = scaled_copy(source, 0.85)
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES)
    frames = frames_of(outcome)
    fingers = ["LeftHandIndex1", "LThumb", "RightHandIndex1", "RThumb"]
    assert set(fingers) <= set(outcome.keyed_bones) and "LeftFingerBase" not in outcome.keyed_bones
    index = bone_indices(source, fingers)
    s_rot = read_pose_frames(source, frames).matrices[:, index, :3, :3]
    t_rot = read_pose_frames(target, frames).matrices[:, index, :3, :3]
    np.testing.assert_allclose(t_rot, s_rot, atol=2e-5)
    assert np.abs(np.diff(s_rot, axis=0)).max() > 1e-3  # the source's fingers do move
