"""What a move of a trunk control carries on a generated Rigify rig: the pairs say it (control_rig), the control
matching places the limbs a move does not carry without evaluating the rig (control_match), and the rig agrees."""

import importlib

import bpy
from mathutils import Matrix
import numpy as np
import pytest

from .test_rigify import generated_rig

LIMB_BONES = {"arm.L": ("upper_arm.L", "forearm.L", "hand.L"), "arm.R": ("upper_arm.R", "forearm.R", "hand.R"),
              "leg.L": ("thigh.L", "shin.L", "foot.L"), "leg.R": ("thigh.R", "shin.R", "foot.R")}


def _org_matrices(rig):
    return {name: np.array(bone.matrix) for name, bone in rig.pose.bones.items() if name.startswith("ORG-")}


@pytest.mark.parametrize("kind", ["basic", "full"])
def test_trunk_pairs_carry_the_limbs_their_controls_move(extension_module_name, kind):
    # Each trunk control turned and shifted: the limbs whose ORG- bones move are exactly those its pair carries
    # (the torso's group: all of them).
    control_match = importlib.import_module(f"{extension_module_name}.bridge.rig.control_match")
    control_rig = importlib.import_module(f"{extension_module_name}.bridge.rig.control_rig")
    rig = generated_rig(kind, "IK")
    bone_map = {group: f"ORG-{bone}" for group, bone in
                [("root", "spine"), ("t1", "spine.001"), ("t2", "spine.002"), ("t3", "spine.003")]
                + [(f"{limb}{k}", b) for limb, bones in LIMB_BONES.items() for k, b in enumerate(bones)]
                + [(f"s{side}", f"shoulder.{side}") for side in "LR"]}
    pairs = [p for p in control_rig.control_pairs(rig, bone_map) if p.level <= 2 and p.control in (
        "torso", "spine_fk", "spine_fk.003", "tweak_spine.001")]
    assert {p.control for p in pairs} == {"torso", "spine_fk", "spine_fk.003", "tweak_spine.001"}
    for pair in pairs:
        control = rig.pose.bones[pair.control]
        kept = control.matrix_basis.copy()
        before = _org_matrices(rig)
        control.matrix_basis = Matrix.Rotation(0.2, 4, 'X') @ Matrix.Translation((0.02, 0.03, 0.01)) @ kept
        bpy.context.view_layer.update()
        after = _org_matrices(rig)
        control.matrix_basis = kept
        bpy.context.view_layer.update()
        moved = {limb for limb, bones in LIMB_BONES.items()
                 if any(np.abs(after[f"ORG-{b}"] - before[f"ORG-{b}"]).max() > 1e-6 for b in bones)}
        said = set(LIMB_BONES) if pair.group == control_match.TRUNK_GROUP else set(pair.carries)
        assert moved == said, (pair.control, moved, said)


def test_a_limb_is_apart_from_a_trunk_part_that_does_not_carry_it(extension_module_name):
    # _carried_or_apart: a move of the hips' control leaves an arm's pair where it is (identity), carries a leg's
    # pair hanging below it by its step, and leaves unknown (None) a leg pair that does not hang below it.
    control_match = importlib.import_module(f"{extension_module_name}.bridge.rig.control_match")
    Pair = control_match.ControlPair
    hips = Pair("hips_control", "hips_bone", 1, group="hips", carries=("leg.L",))
    step = np.eye(4)
    step[:3, 3] = (0.1, 0.2, 0.3)
    arm = Pair("arm_control", "arm_bone", 3, group="arm.L")
    leg = Pair("leg_control", "leg_bone", 3, group="leg.L")
    loose = Pair("foot_control", "foot_bone", 3, group="leg.L")
    above = {"arm_control": {"chest_bone"}, "leg_control": {"hips_bone"}, "foot_control": {"root"}}
    assert np.array_equal(control_match._carried_or_apart(arm, [(hips, step)], above), np.eye(4))
    assert np.array_equal(control_match._carried_or_apart(leg, [(hips, step)], above), step)
    assert control_match._carried_or_apart(loose, [(hips, step)], above) is None
    # The same move of a pair that carries every group (the torso's) leaves the arm unknown.
    torso = Pair("torso", "torso_bone", 0, group=control_match.TRUNK_GROUP)
    assert control_match._carried_or_apart(arm, [(torso, step)], above) is None
