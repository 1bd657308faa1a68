"""Mirroring (solver/retarget/mirror.py, bridge/retarget/mirror.py, the Mirror Pose operator and `retarget --mirror`).

Every check measures Blender's own evaluation (pose bones' matrices after a view layer update or frame_set) against
what it computes here: the sagittal plane from the rest hip joints (the test's own reading of the skeleton), the
partner of each metarig bone by its .L/.R name (the code pairs bones without reading names), plants and slides with
tests/helpers/rig_measures.py."""

import importlib
import json
import shutil
from math import radians
from pathlib import Path

import bpy
import numpy as np
import pytest

from fullbody_adjust.bridge.retarget import run as retarget
from fullbody_adjust.bridge.retarget.read import read_motion, rig_of, source_map
from fullbody_adjust.solver.retarget.mirror import mirror_pose
from fullbody_adjust.bridge.reading.pose import read_pose_frames
from tests.helpers import rig_measures
from tests.helpers.climb_bar import MARGIN, hanging_frames

from .test_retarget import CLIMB, FRAMES, add_metarig, bone_indices, contacts_of, effector_bones, import_clip

REPO = Path(__file__).resolve().parents[2]


def partner_name(name):
    for a, b in ((".L", ".R"), (".R", ".L")):
        if a in name:
            return name.replace(a, b)
    return name


def sagittal_reflection(obj):
    """(4,4) world reflection across the vertical plane halfway between the rest hip joints (thigh heads), normal
    to their horizontal line."""
    world = np.array(obj.matrix_world)
    left, right = (world @ np.append(np.array(obj.data.bones[b].head_local), 1.0) for b in ("thigh.L", "thigh.R"))
    normal = (left - right)[:3]
    normal[2] = 0.0
    normal /= np.linalg.norm(normal)
    middle = 0.5 * (left + right)[:3]
    s = np.eye(4)
    s[:3, :3] -= 2.0 * np.outer(normal, normal)
    s[:3, 3] = 2.0 * (middle @ normal) * normal
    return s


def world_matrices(obj):
    """{bone: world (4,4)} as Blender evaluates the pose."""
    world = np.array(obj.matrix_world)
    return {name: world @ m for name, m in rig_measures.pose_matrices(obj).items()}


def random_pose(obj, seed):
    rng = np.random.default_rng(seed)
    for pb in obj.pose.bones:
        pb.rotation_mode = 'XYZ' if rng.random() < 0.5 else 'QUATERNION'
        if pb.rotation_mode == 'XYZ':
            pb.rotation_euler = rng.normal(0.0, 0.3, 3)
        else:
            q = np.array([1.0, 0.0, 0.0, 0.0]) + rng.normal(0.0, 0.25, 4)
            pb.rotation_quaternion = q / np.linalg.norm(q)
    obj.pose.bones["spine"].location = (0.05, 0.1, -0.03)


def turned_metarig_with_uneven_rolls():
    """The metarig turned 37 degrees about Z, moved and scaled (its object axes are not its facing), the right
    arm's and leg's rolls turned so its rest is not mirror-symmetric, and a random pose."""
    rig = add_metarig(1.3, (1.0, 2.0, 0.0))
    rig.rotation_euler = (0.0, 0.0, radians(37.0))
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode='EDIT')
    for k, name in enumerate(("upper_arm.R", "forearm.R", "hand.R", "thigh.R", "shin.R")):
        rig.data.edit_bones[name].roll += 0.4 + 0.3 * k
    bpy.ops.object.mode_set(mode='OBJECT')
    random_pose(rig, 7)
    bpy.context.view_layer.update()
    return rig


def test_mirror_pose_reflects_each_bones_motion_onto_its_partner_whatever_its_roll():
    """Once: every bone deforms the mesh as its partner did, reflected: a point p on the partner's side moved by
    the partner's motion D_p (world pose @ rest^-1) lands, reflected, where the bone's own new motion takes the
    reflected point (D_j S p = S D_p p), for points around each bone; heads and tails are the partner's,
    reflected. Twice: the original pose, within 1e-6."""
    rig = turned_metarig_with_uneven_rolls()
    s = sagittal_reflection(rig)
    world = np.array(rig.matrix_world)
    rest = {b.name: world @ np.array(b.matrix_local) for b in rig.data.bones}
    before = world_matrices(rig)
    local_before = rig_measures.pose_matrices(rig)
    heads_before = dict(zip((b.name for b in rig.pose.bones), rig_measures.world_heads(rig)))

    bpy.ops.object.mode_set(mode='POSE')
    assert bpy.ops.fullbody_adjust.mirror_pose() == {'FINISHED'}
    after = world_matrices(rig)
    heads_after = dict(zip((b.name for b in rig.pose.bones), rig_measures.world_heads(rig)))
    rng = np.random.default_rng(3)
    worst, swapped = 0.0, 0
    for name in after:
        partner = partner_name(name)
        swapped += partner != name
        points = np.c_[rest[partner][:3, 3] + rng.normal(0.0, 0.1, (8, 3)), np.ones(8)]  # around the partner
        moved = (s @ (before[partner] @ np.linalg.inv(rest[partner])) @ points.T).T
        mirrored = (after[name] @ np.linalg.inv(rest[name]) @ s @ points.T).T
        worst = max(worst, np.abs(moved - mirrored).max())
        np.testing.assert_allclose(heads_after[name], (s @ np.append(heads_before[partner], 1.0))[:3], atol=2e-5)
    assert swapped == 22 and worst < 2e-5, worst

    assert bpy.ops.fullbody_adjust.mirror_pose() == {'FINISHED'}
    local_twice = rig_measures.pose_matrices(rig)
    assert max(np.abs(local_twice[b] - local_before[b]).max() for b in local_before) < 1e-6


def test_mirror_pose_names_what_it_cannot_do():
    rig = add_metarig(1.0)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode='EDIT')
    rig.data.edit_bones.remove(rig.data.edit_bones["hand.R"])
    bpy.ops.object.mode_set(mode='OBJECT')
    rig.pose.bones["forearm.L"].rotation_euler = (0.3, 0.0, 0.0)
    before = rig_measures.pose_matrices(rig)
    with pytest.raises(RuntimeError, match="cannot mirror: hand.L is mapped to 1 bones, hand.R to 0"):
        bpy.ops.fullbody_adjust.mirror_pose()
    after = rig_measures.pose_matrices(rig)
    assert all(np.array_equal(after[b], before[b]) for b in before)


def test_a_clip_mirrored_twice_is_the_clip():
    source = import_clip()
    rig = rig_of(source, source_map(source))
    frames = np.arange(*FRAMES, dtype=np.float64)
    pose, _world, _how = read_motion(source, rig, frames)
    once = mirror_pose(rig, pose)
    twice = mirror_pose(rig, once)
    assert np.abs(twice - pose).max() < 1e-6 * max(1.0, np.abs(pose).max())
    assert np.abs(once - pose).max() > 0.1  # it did move


def foot_tracks(obj, frames, ankle, ball):
    heads, _rots, _ = rig_measures.sample(frames, [(obj, [ankle, ball])])
    return heads[0][:, 0], heads[0][:, 1]


def test_retarget_mirror_turns_left_foot_plants_into_right_foot_plants_that_do_not_slide():
    """The CMU walk onto the metarig, mirrored: where the clip's left foot is planted (measured on the source as
    rig_measures.plants does) the result's right foot is planted, and slides less than 1 mm; and the other way
    round."""
    source = import_clip()
    target = add_metarig(1.2)
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES, mirror=True, new_action="mirrored")
    assert outcome.action.name == "mirrored"
    frames = outcome.frames.astype(int)
    fps = bpy.context.scene.render.fps / bpy.context.scene.render.fps_base
    source_feet = {side: foot_tracks(source, frames, f"{side}Foot", f"{side}ToeBase") for side in ("Left", "Right")}
    target_feet = {side: foot_tracks(target, frames, f"foot.{side}", f"toe.{side}") for side in ("L", "R")}
    for source_side, target_side in (("Left", "R"), ("Right", "L")):
        planted, which = rig_measures.plants(*source_feet[source_side], fps, 1.0)
        assert planted.sum() > 0.2 * len(frames)
        ankle, ball = target_feet[target_side]
        slid = rig_measures.slides(planted, which, {"ankle": ankle, "ball": ball})
        print(f"mirror: source {source_side} plants ({planted.sum()} frames) -> target foot.{target_side}: slide "
              f"max {slid.max() * 1e3:.3f} mm, p95 {np.percentile(slid, 95) * 1e3:.3f} mm")
        assert slid.max() < 1e-3, (source_side, target_side, slid.max())
    # The sides did swap: where only the clip's left foot is planted, the result's left foot travels.
    left_planted, _ = rig_measures.plants(*source_feet["Left"], fps, 1.0)
    right_planted, _ = rig_measures.plants(*source_feet["Right"], fps, 1.0)
    only_left = left_planted & ~right_planted
    assert only_left.sum() > 0.1 * len(frames)
    ankle = target_feet["L"][0][only_left]
    assert np.ptp(ankle[:, :2], axis=0).max() > 0.1


def test_cli_mirror_writes_the_mirrored_motion(extension_module_name, tmp_path, capsys):
    """`retarget --mirror` through the command function, on the sample scene: the written action's right hand goes
    where the unmirrored run's left hand went, reflected across the target's own plane."""
    cli = importlib.import_module(f"{extension_module_name}.cli")
    path = tmp_path / "retarget_cmu.blend"
    shutil.copyfile(REPO / "sample_scenes" / "retarget_cmu.blend", path)
    common = ["retarget", str(path), "--source", "Source", "--target", "Large", "--frame-start", "20",
              "--frame-end", "40", "--quiet"]
    hands = {}
    for mirrored in (False, True):
        out = tmp_path / f"out_{mirrored}.blend"
        report = tmp_path / f"report_{mirrored}.json"
        code = cli.main(common + ["--output", str(out), "--report", str(report)] + (["--mirror"] if mirrored else []))
        assert code in (0, 1), capsys.readouterr().err
        assert json.loads(report.read_text())["mirror"] is mirrored  # the report says how the action was made
        bpy.ops.wm.open_mainfile(filepath=str(out), load_ui=False)
        target = bpy.data.objects["Large"]
        joints = rig_measures.sample(range(20, 41), [(target, ["LeftHand", "RightHand", "LeftUpLeg", "RightUpLeg"])])[0][0]
        hips = 0.5 * (joints[:, 2] + joints[:, 3])
        hands[mirrored] = {"Left": joints[:, 0] - hips, "Right": joints[:, 1] - hips}  # from the hips' centre
        turn = reflection_of_bvh_rig(target)[:3, :3]
    reflected = hands[False]["Left"] @ turn.T
    error = np.linalg.norm(hands[True]["Right"] - reflected, axis=1)
    print("cli mirror: right hand from the reflected left, median", np.median(error), "max", error.max())
    assert np.median(error) < 0.05, error  # the same motion, mirrored (the retarget adjusts each on its own)
    assert np.median(np.linalg.norm(hands[False]["Left"] - reflected, axis=1)) > 0.1  # and not the same hand


def reflection_of_bvh_rig(obj):
    world = np.array(obj.matrix_world)
    left, right = (world @ np.append(np.array(obj.data.bones[b].head_local), 1.0) for b in ("LeftUpLeg", "RightUpLeg"))
    normal = (left - right)[:3]
    normal[2] = 0.0
    normal /= np.linalg.norm(normal)
    s = np.eye(4)
    s[:3, :3] -= 2.0 * np.outer(normal, normal)
    s[:3, 3] = 2.0 * (0.5 * (left + right)[:3] @ normal) * normal
    return s


@pytest.mark.parametrize("name", ["kenney", "metarig_fbx", "metarig_fbx_auto_orient"])
def test_mirror_pose_on_imported_rigs_whose_rolls_are_the_importers(name):
    """Characters as Blender's FBX importer leaves them (rolls along whatever axis it chose, centimetres under an
    object scale): posed at random, mirrored once, each joint the test knows as the character's own left (its file's
    names, tests/helpers/real_rigs.py) is where its right partner was, reflected, and the other way round, within
    1e-5 leg lengths; mirrored twice, every bone's armature-space matrix is back within 1e-6 (positions in leg
    lengths)."""
    from tests.helpers import real_rigs

    rig = real_rigs.load(name)
    obj = rig.armature
    world = np.array(obj.matrix_world)
    heads = dict(zip((b.name for b in obj.pose.bones), rig_measures.world_heads(obj)))
    hip_left, hip_right = heads[rig.bone("hip.L")], heads[rig.bone("hip.R")]
    legs = float(np.linalg.norm(hip_left - heads[rig.bone("ankle.L")]))
    normal = hip_left - hip_right
    normal[2] = 0.0
    normal /= np.linalg.norm(normal)
    s = np.eye(4)
    s[:3, :3] -= 2.0 * np.outer(normal, normal)
    s[:3, 3] = 2.0 * (0.5 * (hip_left + hip_right) @ normal) * normal

    rng = np.random.default_rng(11)
    for pb in obj.pose.bones:
        pb.rotation_mode = 'QUATERNION'
        q = np.array([1.0, 0.0, 0.0, 0.0]) + rng.normal(0.0, 0.2, 4)
        pb.rotation_quaternion = q / np.linalg.norm(q)
    bpy.context.view_layer.update()
    before_heads = dict(zip((b.name for b in obj.pose.bones), rig_measures.world_heads(obj)))
    before = rig_measures.pose_matrices(obj)

    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.fullbody_adjust.mirror_pose() == {'FINISHED'}
    after_heads = dict(zip((b.name for b in obj.pose.bones), rig_measures.world_heads(obj)))
    worst = 0.0
    for role in real_rigs.ROLES:
        left, right = rig.bone(f"{role}.L"), rig.bone(f"{role}.R")
        if left is None:
            continue
        for a, b in ((left, right), (right, left)):
            worst = max(worst, np.linalg.norm(after_heads[a] - (s @ np.append(before_heads[b], 1.0))[:3]) / legs)
    print(f"{name}: mirrored joints off the reflected partner's by {worst:.2e} leg lengths")
    assert worst < 1e-5

    assert bpy.ops.fullbody_adjust.mirror_pose() == {'FINISHED'}
    twice = rig_measures.pose_matrices(obj)
    size = legs / float(np.linalg.norm(world[:3, 0]))  # the legs' length in armature units
    error = max(max(np.abs(twice[b][:3, :3] - before[b][:3, :3]).max(),
                    np.abs(twice[b][:3, 3] - before[b][:3, 3]).max() / size) for b in before)
    print(f"{name}: mirrored twice, off the original by {error:.2e}")
    assert error < 1e-6


def test_clip_batches_hand_mirror_and_groups_to_their_workers(extension_module_name, tmp_path, capsys, rig):
    """`retarget --source-file CLIP --mirror --groups leg.L,trunk` in a worker process writes the keys the bridge
    writes in this process with the same options (and not those it writes without them)."""
    from tests.helpers.bvh import MOCAP_DIR, cut_bvh
    from .test_cli import keyed_values

    cli = importlib.import_module(f"{extension_module_name}.cli")
    clip_import = importlib.import_module(f"{extension_module_name}.bridge.retarget.clip_import")
    run = importlib.import_module(f"{extension_module_name}.bridge.retarget.run")
    files = importlib.import_module(f"{extension_module_name}.bridge.files")
    clip = tmp_path / "walk.bvh"
    cut_bvh(MOCAP_DIR / "cmu_07_01_walk.bvh", clip, 1, 100)
    rig.name = "Hero"
    character = tmp_path / "hero.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(character))

    out = tmp_path / "out"
    code = cli.main(["retarget", str(character), "--target", "Hero", "--source-file", str(clip), "--jobs", "1",
                     "--mirror", "--groups", "leg.L,trunk", "--output-dir", str(out), "--quiet"])
    assert code in (0, 1), capsys.readouterr().err
    bpy.ops.wm.open_mainfile(filepath=str(out / "walk.blend"), load_ui=False)
    batch = keyed_values(bpy.data.objects["Hero"].animation_data.action)

    here = {}
    for options in ({"mirror": True, "groups": ("trunk", "leg.L")}, {}):
        bpy.ops.wm.open_mainfile(filepath=str(character), load_ui=False)
        source, _ = clip_import.import_clip(bpy.context, str(clip), clip_import.ImportOptions())
        start, end = files.frame_range(source, bpy.context.scene)
        outcome = run.retarget(bpy.context, source, bpy.data.objects["Hero"], start, end, floor=0.0,
                               contacts=[["ground", None]], new_action="walk", **options)
        here[bool(options)] = keyed_values(outcome.action)
    assert batch.keys() == here[True].keys() and batch.keys() != here[False].keys()
    for key, (frames, values) in batch.items():
        np.testing.assert_array_equal(frames, here[True][key][0])
        np.testing.assert_allclose(values, here[True][key][1], atol=1e-6)


def test_retarget_mirror_holds_the_hand_on_the_mirrored_contact_object():
    """The climb clip hangs from a bar with both hands; a ledge is built here around the left wrist's hanging
    positions only, 2 cm larger on every side, off to the source's left. Retargeted mirrored onto the metarig with
    the floor and the ledge as contacts, the ledge goes with the mirrored clip: the right hand (no longer the left)
    holds it, within 5 cm of the ledge reflected across the source's hip line (the test's own reading of its
    sagittal plane) on every frame the report says it holds, and farther than 10 cm from where the ledge stands;
    the left hand touches no object."""
    source = import_clip(CLIMB, fps=30)
    lo, hi = source.animation_data.action.frame_range
    frames = np.arange(int(np.ceil(lo)) + 1, int(hi) + 1, dtype=float)
    heads = read_pose_frames(source, frames).heads
    wrists = heads[:, bone_indices(source, ["LeftHand", "RightHand"])]
    left = wrists[hanging_frames(wrists, 30), 0]
    ledge_lo, ledge_hi = left.min(axis=0) - MARGIN, left.max(axis=0) + MARGIN
    bpy.ops.mesh.primitive_cube_add(location=(ledge_lo + ledge_hi) / 2)
    ledge = bpy.context.active_object
    ledge.name, ledge.scale = "Ledge", (ledge_hi - ledge_lo) / 2
    bpy.context.view_layer.update()
    s = reflection_of_bvh_rig(source)
    corners = np.array([[(ledge_lo, ledge_hi)[(c >> a) & 1][a] for a in range(3)] for c in range(8)])
    mirrored = corners @ s[:3, :3].T + s[:3, 3]
    mirror_lo, mirror_hi = mirrored.min(axis=0), mirrored.max(axis=0)

    target = add_metarig(1.0, location=(0.0, 0.0, 0.0))
    outcome = retarget.retarget(bpy.context, source, target, int(frames[0]), int(frames[-1]), mirror=True,
                                contacts=["ground", ("object", "Ledge")])
    snapshot = read_pose_frames(target, frames)
    effectors = outcome.contact_report["effectors"]
    assert not [c for c in effectors["hand.L"]["contacts"] if c["kind"] == "object"]
    runs = contacts_of(outcome, "hand.R", "object")
    assert runs and {c["touches"] for c in effectors["hand.R"]["contacts"] if c["kind"] == "object"} == {"Ledge"}
    hand = bone_indices(target, effector_bones(target)[1:2])[0]
    assert target.data.bones[hand].name.endswith(".R")

    def distance(points, lo, hi):
        return np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=-1)

    on = np.concatenate([np.arange(a, b) for a, b in runs])
    points = np.stack([snapshot.heads[on, hand], snapshot.tails[on, hand]], axis=1)
    assert distance(points, mirror_lo, mirror_hi).min(axis=1).max() < 0.05
    assert distance(points, ledge_lo, ledge_hi).min(axis=1).min() > 0.10
