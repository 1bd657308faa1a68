"""Joints, not tails: a rig whose tails an importer left far past the next joint (as Blender's glTF importer
does) is solved exactly as the same rig with its tails on the joints."""

import importlib
import re

import bpy
import numpy as np
import pytest

from .scene_tools import Pose, add_rig, bone_map, parse_report, place, slot
from .test_adjust_pose import reach_left_hand


def _far_tails(obj, factor):
    """Every bone disconnected, its tail moved ``factor`` times as far from its head (direction and roll kept)."""
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    for bone in obj.data.edit_bones:
        bone.use_connect = False
    for bone in obj.data.edit_bones:
        roll = bone.roll
        bone.tail = bone.head + factor * (bone.tail - bone.head)
        bone.roll = roll
    bpy.ops.object.mode_set(mode='OBJECT')
    bpy.context.view_layer.update()


def _solve(task, factor, capfd):
    obj = add_rig("basic")  # a second rig in the same file is solved on its own (its own targets)
    if factor != 1.0:
        _far_tails(obj, factor)
    bpy.ops.fullbody_adjust.create_targets()
    before = Pose(obj)
    reach_left_hand(obj, before, task)
    capfd.readouterr()
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    report = parse_report(capfd.readouterr().out)
    after = Pose(obj)
    return obj, before, after, report


@pytest.mark.parametrize("task", ("trunk", "pelvis"))
def test_far_tails_solve_as_joints(task, capfd):
    obj, before, after, report = _solve(task, 1.0, capfd)
    joints = after.heads.copy()
    far_obj, far_before, far_after, far_report = _solve(task, 100.0, capfd)
    np.testing.assert_allclose(far_before.heads, before.heads, atol=1e-5)  # the same rest joints (float32)
    height = before.height()
    # The same solve: every joint where the tidy rig's went, the same targets met.
    assert far_report[:2] == report[:2] and report[0] == report[1]
    np.testing.assert_allclose(far_after.heads, joints, atol=1e-5 * height)
    root = bone_map(far_obj)["root"][0]
    moved = np.linalg.norm(far_after.head(root) - far_before.head(root))
    assert (moved > 0.05 * height) == (task == "pelvis")


def _in_centimetres(obj):
    """The armature's data in centimetres (every rest position ×100) under an object scale of 0.01, as FBX
    imports from some tools come: the same character in the world."""
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    obj.scale = (100.0, 100.0, 100.0)
    bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
    obj.scale = (0.01, 0.01, 0.01)
    bpy.context.view_layer.update()


def _numbers(text):
    return [float(x) for x in re.findall(r"\d+\.\d+(?:e-?\d+)?", text)]


def test_units_and_object_scale_give_world_figures(capfd):
    """A far target beyond every reach on the same character in metres and in centimetres under an object scale
    of 0.01: the same world pose, and a report whose every figure (residual, the reach in its reason) is the same
    world distance."""
    reports, poses = [], []
    for centimetres in (False, True):
        obj = add_rig("basic")
        if centimetres:
            _in_centimetres(obj)
        bpy.ops.fullbody_adjust.create_targets()
        before = Pose(obj)
        reach_left_hand(obj, before, "trunk")
        place(slot(obj, "hand.L").target, before.to_world(before.head(bone_map(obj)["hand.L"][0]))
              + np.array([0.0, -3.0, 0.5]) * before.height())
        capfd.readouterr()
        assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
        reports.append(capfd.readouterr().out.strip().splitlines()[-1])
        poses.append(Pose(obj).world_heads)
    assert "beyond" in reports[0], reports[0]
    np.testing.assert_allclose(poses[1], poses[0], atol=1e-5 * Pose(obj).height())
    plain, scaled = _numbers(reports[0]), _numbers(reports[1])
    assert len(plain) == len(scaled) >= 2, reports
    np.testing.assert_allclose(scaled, plain, rtol=1e-3)


def test_preview_draws_bones_to_their_joints(extension_module_name):
    """The command line's preview draws each bone from its head to where it ends as a joint: on a rig whose tails
    lie 100 times past the next joint, to its child's head (a leaf no longer than its parent)."""
    batch = importlib.import_module(f"{extension_module_name}.bridge.files")
    obj = add_rig("basic")
    _far_tails(obj, 100.0)
    segments = batch.skeleton_segments(obj, [1])[0]  # every bone deforms
    pose = Pose(obj)
    index = {name: k for k, name in enumerate(pose.names)}
    for bone in obj.data.bones:
        start, end = segments[index[bone.name]]
        np.testing.assert_allclose(start, pose.world_heads[index[bone.name]], atol=1e-6)
        kids = [c for c in bone.children if (c.head_local - bone.head_local).length > 1e-4]
        if len(kids) == 1:
            np.testing.assert_allclose(end, pose.world_heads[index[kids[0].name]], atol=1e-5)
        elif not kids and bone.parent is not None:
            assert np.linalg.norm(end - start) <= 1.0001 * np.linalg.norm(
                segments[index[bone.parent.name]][1] - segments[index[bone.parent.name]][0])
