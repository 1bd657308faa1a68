"""Retargeting a captured clip onto a generated Rigify rig: the new action keys the rig's controls, and Blender's
evaluation of the deform bones follows the plan (wrists and ankles on their targets, planted feet still)."""

import bpy
import numpy as np

from fullbody_adjust.bridge.rig import mapping
from fullbody_adjust.bridge.retarget import run as retarget
from fullbody_adjust.bridge.retarget.read import rig_of
from fullbody_adjust.solver.retarget import motion as rt

from .test_retarget import enable_addon, import_clip
from .test_rigify import INTERNAL, keyed_bones

FRAMES = (2, 41)
# Deform bones whose heads are the wrists and ankles, in rt.EFFECTORS order.
DEFORM_ENDS = {"hand.L": "DEF-hand.L", "hand.R": "DEF-hand.R", "foot.L": "DEF-foot.L", "foot.R": "DEF-foot.R"}


def test_a_clip_onto_a_generated_rig_keys_its_controls():
    source = import_clip()
    enable_addon("rigify")
    bpy.ops.object.armature_basic_human_metarig_add()
    bpy.ops.pose.rigify_generate()
    rig = bpy.context.active_object
    rig.location = (1.5, 0.0, 0.0)
    bpy.context.view_layer.update()

    outcome = retarget.retarget(bpy.context, source, rig, *FRAMES)

    assert outcome.action is rig.animation_data.action
    keyed = keyed_bones(rig)
    assert keyed == set(outcome.keyed_bones) and keyed
    assert not any(name.startswith(INTERNAL) for name in keyed), keyed
    assert {"torso", "hand_ik.L", "foot_ik.L"} <= keyed
    size = rt.leg_length(rig_of(rig, mapping.load_map(rig)))
    heads = np.empty((FRAMES[1] - FRAMES[0] + 1, len(rt.EFFECTORS), 3))
    feet = {e: np.empty((len(heads), 2, 3)) for e in ("foot.L", "foot.R")}  # ankle and ball: the mapped foot
    for row, frame in enumerate(range(FRAMES[0], FRAMES[1] + 1)):
        bpy.context.scene.frame_set(frame)
        for k, effector in enumerate(rt.EFFECTORS):
            heads[row, k] = rig.matrix_world @ rig.pose.bones[DEFORM_ENDS[effector]].head
        for effector, points in feet.items():
            bone = rig.pose.bones[DEFORM_ENDS[effector]]
            points[row] = [rig.matrix_world @ bone.head, rig.matrix_world @ bone.tail]
    reach = np.linalg.norm(heads - outcome.targets, axis=-1)
    assert np.percentile(reach, 99) < 1e-4 * size and reach.max() < 1e-3 * size, reach.max() / size
    for k, effector in enumerate(rt.EFFECTORS):
        for c in outcome.contact_report["effectors"][effector]["contacts"]:
            # Planted: the foot turns about one of its points (ankle or ball), which stays still.
            assert c["kind"] == "ground" and effector.startswith("foot")
    for effector, points in feet.items():
        for c in outcome.contact_report["effectors"][effector]["contacts"]:
            a, b = c["start"], c["stop"]
            steps = np.linalg.norm(np.diff(points[a:b, :, :2], axis=0), axis=-1).min(axis=1)  # the stillest point
            assert steps.sum() < 1e-3 * size
    assert outcome.contacts[:, 2:].any()  # the walk plants its feet in these frames
