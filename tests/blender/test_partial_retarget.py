"""`retarget --groups`: only the body groups asked for are carried; every other bone keeps the target's own F-Curves
bit for bit (solver/retarget/partial.py, bridge/retarget/partial.py), through the command function as
`blender -b FILE -c fullbody_adjust retarget ...` runs it.

The target is the metarig with an action of its own (keys on every bone, some Bezier, some constant, one curve with
moved handles). Measured in the written file, reopened: the new action's F-Curves against the target's own action
(kept in the file), and Blender's evaluated local rotations against a full retarget's and the target's own."""


import bpy
import numpy as np
import pytest

from tests.helpers import rig_measures
from tests.helpers.blender_data import bone_map

from .test_keyframes import fcurves_of
from .test_retarget import FRAMES, add_metarig, import_clip

FIRST, LAST = 2, 61
GROUPS = ("arm.L", "leg.R")
PARTS = {"arm.L": ("arm.L", "hand.L"), "leg.R": ("leg.R", "foot.R")}


def own_action(rig):
    """Keys on every bone of ``rig`` at four frames: random rotations, the spine's location too; the hand.L and
    thigh.R keys constant, one handle of forearm.R moved by hand."""
    rng = np.random.default_rng(5)
    for frame in (FIRST, 20, 40, LAST):
        for pb in rig.pose.bones:
            q = np.array([1.0, 0.0, 0.0, 0.0]) + rng.normal(0.0, 0.15, 4)
            pb.rotation_quaternion = q / np.linalg.norm(q)
            pb.keyframe_insert("rotation_quaternion", frame=frame)
        rig.pose.bones["spine"].location = rng.normal(0.0, 0.05, 3)
        rig.pose.bones["spine"].keyframe_insert("location", frame=frame)
    action = rig.animation_data.action
    action.name = "Own"
    curves = [fc for fc in rig_measures.animating_fcurves(rig)]
    for fc in curves:
        if '"hand.L"' in fc.data_path or '"thigh.R"' in fc.data_path:
            for point in fc.keyframe_points:
                point.interpolation = 'CONSTANT'
        if '"forearm.R"' in fc.data_path and fc.array_index == 1:
            fc.keyframe_points[1].handle_left_type = 'FREE'
            fc.keyframe_points[1].handle_left[1] += 0.3
    return action


@pytest.fixture
def scene(tmp_path):
    source = import_clip()
    source.name = "Walk"
    target = add_metarig(1.2)
    target.name = "Target"
    own_action(target)
    path = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def run(cli, capsys, *argv):
    code = cli.main([str(a) for a in argv])
    return code, *capsys.readouterr()


def carried_bones(rig, groups):
    """The bones the stored map puts in ``groups`` (the basic metarig's hands have no fingers to carry)."""
    stored = bone_map(rig)
    return {b for g in groups for part in PARTS[g] for b in stored.get(part, ())}


def local_rotations_over(rig, frames):
    out = []
    for frame in frames:
        bpy.context.scene.frame_set(frame)
        out.append(rig_measures.local_rotations(rig))
    return {name: np.array([f[name] for f in out]) for name in out[0]}


def test_only_the_groups_asked_for_are_carried_and_every_other_curve_is_the_targets_own(cli, capsys, tmp_path, scene):
    full, partial = tmp_path / "full.blend", tmp_path / "partial.blend"
    common = ["retarget", scene, "--source", "Walk", "--target", "Target", "--frame-start", FIRST, "--frame-end", LAST,
              "--quiet"]
    code, _, err = run(cli, capsys, *common, "--new-action", "Full", "--output", full)
    assert code in (0, 1), err
    bpy.ops.wm.open_mainfile(filepath=str(full), load_ui=False)  # the next run opens the scene afresh
    code, _, err = run(cli, capsys, *common, "--groups", ",".join(GROUPS), "--new-action", "Partial",
                       "--output", partial)
    # The feet on the target's own trunk cannot hold the clip's plants, and the run says so (measured on what it
    # wrote, not on the full solve).
    assert code == 1 and "does not hold its contact" in err, err

    bpy.ops.wm.open_mainfile(filepath=str(full), load_ui=False)
    frames = range(FIRST, LAST + 1, 7)
    full_rotations = local_rotations_over(bpy.data.objects["Target"], frames)
    bpy.ops.wm.open_mainfile(filepath=str(partial), load_ui=False)
    target = bpy.data.objects["Target"]
    own, written = bpy.data.actions["Own"], target.animation_data.action
    assert written.name == "Partial" and own.use_fake_user
    carried = carried_bones(target, GROUPS)
    assert carried >= {"upper_arm.L", "forearm.L", "hand.L", "thigh.R", "shin.R", "foot.R"}
    before, after = fcurves_of(target, own), fcurves_of(target, written)

    def bone(key):
        return key[0].split('"')[1]

    # Every curve of every other bone: the target's own, bit for bit (keys, handles, interpolation, group).
    kept = {key for key in before if bone(key) not in carried}
    assert {key for key in after if bone(key) not in carried} == kept
    for key in kept:
        for field in ("co", "left", "right", "interpolation"):
            assert after[key][field].tobytes() == before[key][field].tobytes(), (key, field)
        assert after[key]["group"] == before[key]["group"]
    # The carried bones: keyed on every frame of the range, by the retarget.
    assert {bone(key) for key in after} - {bone(key) for key in kept} == carried
    for key in after:
        if bone(key) in carried:
            np.testing.assert_array_equal(after[key]["co"][:, 0], np.arange(FIRST, LAST + 1))

    # Evaluated: the carried bones turn as the full retarget turns them, the others as the target's own action.
    partial_rotations = local_rotations_over(target, frames)
    target.animation_data.action = own
    if bpy.app.version >= (4, 4, 0):
        target.animation_data.action_slot = own.slots[0]
    own_rotations = local_rotations_over(target, frames)
    for name, rotations in partial_rotations.items():
        expected = full_rotations[name] if name in carried else own_rotations[name]
        angle = rig_measures.angle_between_rotations(rotations, expected)
        assert angle.max() < 1e-3, (name, angle.max())
    assert max(rig_measures.angle_between_rotations(full_rotations[b], own_rotations[b]).max() for b in carried) > 5.0


@pytest.mark.parametrize("groups, words", [("trunk,tail", "unknown body group 'tail'"),
                                           ("", "unknown body group ''"),
                                           ("arm.L,head", "unknown body group 'head'")])
def test_an_unknown_group_is_one_line_and_exit_2(cli, capsys, tmp_path, groups, words):
    code, out, err = run(cli, capsys, "retarget", tmp_path / "none.blend", "--source", "S", "--target", "T",
                         "--groups", groups)
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err


def test_groups_are_read_in_any_case_and_order(cli):
    args = cli.build_parser().parse_args(["retarget", "F", "--source", "S", "--target", "T", "--groups",
                                          "LEG.r, trunk,arm.l"])
    assert args.groups == ("trunk", "arm.L", "leg.R")


def test_trunk_and_legs_carried_hold_the_clips_plants_while_the_arms_keep_their_own_keys(capsys):
    """--groups trunk,leg.L,leg.R (through the bridge): where the clip's foot is planted (rig_measures.plants on the
    source) the target's same foot slides less than 1 mm, the report holds every contact, and the arms' F-Curves
    are the target's own."""
    from fullbody_adjust.bridge.retarget import run as retarget

    source = import_clip()
    target = add_metarig(1.2)
    own = own_action(target)
    before = fcurves_of(target, own)
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES, groups=("trunk", "leg.L", "leg.R"))
    assert outcome.contacts_not_held() == 0
    after = fcurves_of(target, outcome.action)
    arms = carried_bones(target, ("arm.L",)) | {b.replace(".L", ".R") for b in carried_bones(target, ("arm.L",))}
    for key in before:
        if key[0].split('"')[1] in arms:
            assert all(after[key][f].tobytes() == before[key][f].tobytes() for f in ("co", "left", "right"))
    frames = np.arange(FRAMES[0], FRAMES[1] + 1)
    fps = bpy.context.scene.render.fps / bpy.context.scene.render.fps_base
    for side, suffix in (("Left", "L"), ("Right", "R")):
        tracks = rig_measures.sample(frames, [(source, [f"{side}Foot", f"{side}ToeBase"]),
                                              (target, [f"foot.{suffix}", f"toe.{suffix}"])])[0]
        planted, which = rig_measures.plants(tracks[0][:, 0], tracks[0][:, 1], fps, 1.0)
        assert planted.sum() > 0.2 * len(frames)
        slid = rig_measures.slides(planted, which, {"ankle": tracks[1][:, 0], "ball": tracks[1][:, 1]})
        print(f"partial trunk+legs: {side} plants {planted.sum()} frames, slide max {slid.max() * 1e3:.4f} mm")
        assert slid.max() < 1e-3, (side, slid.max())


@pytest.mark.parametrize("mode", ["object", "in-place"])
def test_groups_with_root_motion_is_one_line_and_the_file_untouched(cli, capsys, scene, mode):
    before = scene.read_bytes()
    code, out, err = run(cli, capsys, "retarget", scene, "--source", "Walk", "--target", "Target",
                         "--groups", "arm.L", "--root-motion", mode, "--overwrite")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"--root-motion {mode}" in err and "--groups" in err, err
    assert scene.read_bytes() == before
