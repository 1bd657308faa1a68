"""How many times placing a generated Rigify rig's controls evaluates the rig, and how exactly it places them
(control_match): after a sweep's closing evaluation, an IK end control's correction of its chain's own miss is not
evaluated before the chain's bend and scale steps, and an IK chain's middle joint (no target) is held to 10x the
solve's tolerance, its hands and feet to the tolerance."""

import importlib

import bpy
import numpy as np
import pytest

from .scene_tools import Pose, body_axes, chain_joints, chain_length, place, slot
from .test_adjust_pose import REACH
from .test_rigify import generated_rig, world_head

# What the deform bones are held to (the brief's 0.1 mm; the rigs are in metres).
ELBOW = 1e-4


class CountingViewLayer:
    """A view layer whose updates (evaluations of the rig) are counted in ``counts[-1]``."""

    def __init__(self, view_layer, counts):
        self.view_layer, self.counts = view_layer, counts

    def update(self):
        self.counts[-1] += 1
        self.view_layer.update()


def test_a_chain_end_correction_leaves_its_bend_and_scale_to_the_last_evaluation(extension_module_name):
    # _carried_or_apart: a move of an arm's IK end control marked as a correction leaves that arm's bend and scale
    # pairs placed from the last evaluation (the identity); the same move unmarked asks for an evaluation (None),
    # and a rigid pair of the limb is carried or not as before.
    control_match = importlib.import_module(f"{extension_module_name}.bridge.rig.control_match")
    Pair = control_match.ControlPair
    hand = Pair("hand_ik.L", "ORG-hand.L", 3, group="arm.L", follows_control=True)
    bend = Pair("upper_arm_ik.L", "ORG-upper_arm.L", 4, end="ORG-hand.L", kind="bend", group="arm.L")
    scale = Pair("upper_arm_ik.L", "ORG-upper_arm.L", 4, end="ORG-hand.L", kind="scale", group="arm.L")
    fk = Pair("forearm_fk.L", "ORG-forearm.L", 4, group="arm.L")
    other = Pair("upper_arm_ik.R", "ORG-upper_arm.R", 4, end="ORG-hand.R", kind="bend", group="arm.R")
    step = np.eye(4)
    step[:3, 3] = (1e-5, 0.0, 2e-5)
    above = {"upper_arm_ik.L": {"MCH-upper_arm_ik_swing.L"}, "forearm_fk.L": {"hand_ik.L"},
             "upper_arm_ik.R": {"MCH-upper_arm_ik_swing.R"}}
    pending = [(hand, step)]
    for pair in (bend, scale):
        assert np.array_equal(control_match._carried_or_apart(pair, pending, above, {hand}), np.eye(4))
        assert control_match._carried_or_apart(pair, pending, above) is None
    assert np.array_equal(control_match._carried_or_apart(fk, pending, above, {hand}), step)
    assert np.array_equal(control_match._carried_or_apart(other, pending, above, {hand}), np.eye(4))


def _drag(rig, before, steps=5):
    """World goals of the left hand: a few steps within the arm's reach around its wrist."""
    up, _left, forward = body_axes(rig, before)
    arm = chain_joints(rig, before, "arm.L")
    reach = chain_length(arm)
    return [before.to_world(arm[-1] + 0.12 * reach * (np.cos(k) * up + np.sin(k) * forward + 0.3 * k / steps * up))
            for k in range(steps)]


@pytest.mark.parametrize("limbs", ["IK", "FK"])
def test_live_places_controls_as_exactly_with_fewer_evaluations(extension_module_name, monkeypatch, limbs):
    """Live on a generated rig, the left hand's target dragged: each update shows the left hand on its target,
    every ORG- bone the matching places within 0.1 mm of the solve (the elbow's where the matching ends
    within its tolerances), with no more evaluations of the rig than with both rules off (every correction
    evaluated first, the middle joints to the tolerance) and, on IK arms, fewer in all; FK arms in one evaluation."""
    control_match = importlib.import_module(f"{extension_module_name}.bridge.rig.control_match")
    match = control_match.match_controls
    counts, placed = [], []

    def counted(obj, view_layer, pairs, desired, tolerance, **options):
        counts.append(0)
        placed.append((pairs, desired, tolerance))
        return match(obj, CountingViewLayer(view_layer, counts), pairs, desired, tolerance, **options)

    monkeypatch.setattr(control_match, "match_controls", counted)
    totals = {}
    for rules in (True, False):
        if not rules:
            monkeypatch.setattr(control_match, "_CORRECTION", 0.0)
            monkeypatch.setattr(control_match, "_MIDDLE_JOINT", 1.0)
        bpy.ops.wm.read_homefile(use_empty=True)
        rig = generated_rig("basic", limbs)
        before = Pose(rig)
        rig.fullbody_adjust.live = True
        counts.clear()
        for goal in _drag(rig, before):
            placed.clear()
            place(slot(rig, "hand.L").target, goal)
            after = Pose(rig)  # evaluates the scene: the live handler solves
            assert np.linalg.norm(world_head(after, "DEF-hand.L") - goal) <= REACH * before.height(), (rules, goal)
            assert len(placed) == 1
            pairs, desired, tolerance = placed[0]
            assert tolerance <= 1e-5
            for bone in {p.bone for p in pairs} | {p.end for p in pairs if p.end}:
                now = np.array(rig.pose.bones[bone].matrix)
                assert np.linalg.norm(now[:3, 3] - desired[bone][:3, 3]) <= ELBOW, (rules, bone)
        rig.fullbody_adjust.live = False
        totals[rules] = list(counts)
    assert sum(totals[True]) <= sum(totals[False]), totals
    if limbs == "IK":
        assert sum(totals[True]) < sum(totals[False]), totals
    else:  # FK arms: placed in one go, the one evaluation showing the result (a Live update has just evaluated)
        assert totals[True] == [1] * len(totals[True]), totals


def test_an_ik_chain_predicted_after_its_end_moves_saves_evaluations(extension_module_name, monkeypatch):
    """Live on a generated rig with IK arms, the left hand's target dragged: the arm's bend and scale stepped from
    the chain predicted after its hand control's move (chain_prediction) place every ORG- bone as exactly, with
    fewer evaluations of the rig in all than when the chain is evaluated before those steps."""
    control_match = importlib.import_module(f"{extension_module_name}.bridge.rig.control_match")
    match, predicted = control_match.match_controls, control_match._predicted
    counts = []

    def counted(obj, view_layer, pairs, desired, tolerance, **options):
        counts.append(0)
        error = match(obj, CountingViewLayer(view_layer, counts), pairs, desired, tolerance, **options)
        for bone in {p.bone for p in pairs} | {p.end for p in pairs if p.end}:
            assert np.linalg.norm(np.array(obj.pose.bones[bone].matrix)[:3, 3] - desired[bone][:3, 3]) <= ELBOW
        return error

    monkeypatch.setattr(control_match, "match_controls", counted)
    totals, used = {}, []

    def recorded(*args):
        carry = predicted(*args)
        used.append(carry is not None)
        return carry

    for predicting in (True, False):
        monkeypatch.setattr(control_match, "_predicted", recorded if predicting else (lambda *args: None))
        bpy.ops.wm.read_homefile(use_empty=True)
        rig = generated_rig("basic", "IK")
        before = Pose(rig)
        rig.fullbody_adjust.live = True
        counts.clear()
        for goal in _drag(rig, before, steps=8):
            place(slot(rig, "hand.L").target, goal)
            after = Pose(rig)  # evaluates the scene: the live handler solves
            assert np.linalg.norm(world_head(after, "DEF-hand.L") - goal) <= REACH * before.height(), goal
        rig.fullbody_adjust.live = False
        totals[predicting] = list(counts)
    assert any(used), "no chain was predicted"
    assert sum(totals[True]) < sum(totals[False]), totals


def test_a_chain_scale_solves_its_stretch_samples(extension_module_name):
    # chain_steps: samples (x, l, m) of a chain whose length over its base's scale follows a line in x give the scale
    # at which the modelled chain has the wanted length with its end where it is; where the chain's length no
    # longer follows the scale (a slope in logs under _SLOPE_MIN: near full stretch) there is none.
    steps = importlib.import_module(f"{extension_module_name}.bridge.rig.chain_steps")
    length, slope, at = 0.3, 0.12, (1.5, 1.9)  # first bone's length; l(x) = at[1] + slope (x - at[0])

    def stretch(x):
        return at[1] + slope * (x - at[0])

    bone = np.eye(4)
    end = (0.0, 0.0, 0.47)
    d = 0.47 / length
    samples = []
    for x, scale in ((1.45, 1.0), (1.55, 0.98)):
        # a chain standing at x with that scale: its end at x s c, its length s c l(x)
        chain = (bone.tolist(), (0.0, 0.0, x * scale * length), scale * length * stretch(x))
        steps.record_stretch(samples, chain, scale, length)
    assert np.allclose(samples, [(1.45, stretch(1.45), 0.0), (1.55, stretch(1.55), 0.0)])  # (x, l, miss)
    want = 0.5651
    scale = steps._modelled_scale(samples, (bone.tolist(), end, 0.0), want, length)
    assert scale is not None
    assert abs(scale * length * stretch(d / scale) - want) < 1e-9
    steep = [(1.45, 1.0), (1.55, 1.1)]  # l' = 1 from l = 1: l - x l' < 0, the length falls as the scale grows
    assert steps._modelled_scale(steep, (bone.tolist(), end, 0.0), want, length) is None


def test_pole_arms_are_placed_from_evaluations_as_exactly(extension_module_name, monkeypatch):
    """Live on a generated rig whose arms use their pole controls, the left hand's target dragged: a chain with a
    pole is not predicted (the pole sets its bend plane), and every ORG- bone is placed within 0.1 mm as without."""
    control_match = importlib.import_module(f"{extension_module_name}.bridge.rig.control_match")
    match, placed = control_match.match_controls, []

    def checked(obj, view_layer, pairs, desired, tolerance, **options):
        error = match(obj, view_layer, pairs, desired, tolerance, **options)
        placed.append({p.control for p in pairs if p.kind == "bend"})
        for bone in {p.bone for p in pairs} | {p.end for p in pairs if p.end}:
            assert np.linalg.norm(np.array(obj.pose.bones[bone].matrix)[:3, 3] - desired[bone][:3, 3]) <= ELBOW
        return error

    monkeypatch.setattr(control_match, "match_controls", checked)
    bpy.ops.wm.read_homefile(use_empty=True)
    rig = generated_rig("basic", "IK")
    for side in "LR":
        rig.pose.bones[f"upper_arm_parent.{side}"]["pole_vector"] = True
    bpy.context.view_layer.update()
    before = Pose(rig)
    rig.fullbody_adjust.live = True
    for goal in _drag(rig, before, steps=4):
        place(slot(rig, "hand.L").target, goal)
        after = Pose(rig)  # evaluates the scene: the live handler solves
        assert np.linalg.norm(world_head(after, "DEF-hand.L") - goal) <= REACH * before.height(), goal
    rig.fullbody_adjust.live = False
    assert placed and all({"upper_arm_ik_target.L", "upper_arm_ik_target.R"} <= bends for bends in placed), placed
