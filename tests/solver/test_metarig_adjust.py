"""Adjust Pose on the Rigify full human metarig (159 bones, tests/helpers/metarig.py): one pose solved alone
equals its row of a batch, and a target beyond reach ends at the stretched limb without running every pass.

Expectations are computed here from the rig's own geometry (chain lengths, target distances)."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver.fullbody.adjust import AdjustSettings, adjust_frames, adjust_pose
from fullbody_adjust.solver.limits.human import LimbLimits, default_limits
from fullbody_adjust.solver.obstacles.boxes import points_inside, segments_cross
from tests.helpers import metarig


@pytest.fixture(scope="module")
def rig():
    return metarig.load()


def _frames(rig, targets, boxes, **kwargs):
    model, h, t, x = rig
    n = len(targets)
    return adjust_frames(model, np.repeat(h[None], n, 0), np.repeat(t[None], n, 0), targets, metarig.EFFECTORS,
                         metarig.PRIORITIES, obstacles=boxes, bone_x_axes=np.repeat(x[None], n, 0), **kwargs)


# Six frames: their stacked limbs (12 rows) are solved on arrays, one frame alone one problem at a time on floats
# (maths/lanes.py by_rows, chain/iteration.py).
offsets = arrays(np.float64, (6, 2, 3), elements=st.floats(-0.25, 0.25))


@settings(deadline=None, max_examples=12)
@given(kind=st.sampled_from(metarig.CASES), hand_offsets=offsets)
def test_a_pose_solved_alone_equals_its_row_of_a_batch_within_1e9(rig, kind, hand_offsets):
    model, h, t, x = rig
    base, boxes = metarig.case(model, h, t, kind)
    targets = np.repeat(base[None], len(hand_offsets), 0)
    targets[:, :2] += hand_offsets  # both hands moved differently on each frame; feet planted
    batch = _frames(rig, targets, boxes)
    for f in range(len(targets)):
        one = adjust_pose(model, h, t, targets[f], metarig.EFFECTORS, metarig.PRIORITIES, obstacles=boxes,
                          bone_x_axes=x)
        np.testing.assert_allclose(one.heads, batch.heads[f], atol=1e-9, rtol=0)
        np.testing.assert_allclose(one.tails, batch.tails[f], atol=1e-9, rtol=0)
        np.testing.assert_allclose(one.rotations, batch.rotations[f], atol=1e-9, rtol=0)
        np.testing.assert_allclose(one.residuals, batch.residuals[f], atol=1e-9, rtol=0)
        assert list(one.status) == list(batch.status[f])


@pytest.mark.parametrize("off", [0.5, 2.0, 8.0])
def test_a_hand_just_off_its_target_is_solved_alone_as_in_a_batch(rig, off):
    """A hand `off` tolerances from its target (feet and the other hand where they stand): left untouched within
    the tolerance, solved beyond it, by a pose solved alone exactly as by its row of a batch."""
    model, h, t, x = rig
    tolerance = AdjustSettings().chain.tolerance
    targets = metarig.wrists_and_ankles(model, h)
    targets[0] += off * tolerance * np.array([0.6, 0.0, 0.8])
    one = adjust_pose(model, h, t, targets, metarig.EFFECTORS, metarig.PRIORITIES, bone_x_axes=x)
    batch = _frames(rig, np.repeat(targets[None], 2, 0), None)
    np.testing.assert_array_equal(one.heads, batch.heads[0])
    assert list(one.status) == list(batch.status[0])
    assert one.residuals[0] <= tolerance
    wrist = h[model.limbs["arm.L"].end_bone]
    assert np.array_equal(one.heads[model.limbs["arm.L"].end_bone], wrist) == (off <= 1.0)


def test_a_target_beyond_reach_ends_at_the_stretched_arm(rig):
    """Without joint limits the best pose is the arm straight on the line from its base to the target."""
    model, h, t, x = rig
    targets, _ = metarig.case(model, h, t, "far")
    res = _frames(rig, targets[None], None, settings=replace(AdjustSettings(), use_limits=False))
    arm = model.limbs["arm.L"]
    chain0 = arm.joints(h, t)
    reach = float(np.sum(np.linalg.norm(np.diff(chain0, axis=0), axis=1)))
    base = res.heads[0, arm.bones[0]]
    hand = res.heads[0, arm.end_bone]
    to_target = np.linalg.norm(targets[0] - base)
    assert to_target > reach  # beyond reach even from where the SC went
    assert res.status[0, 0] == "unreachable"
    # The closed-form best pose: the arm at full stretch on the line from its base to the target.
    np.testing.assert_allclose(np.linalg.norm(hand - base), reach, rtol=1e-9)
    np.testing.assert_allclose(res.residuals[0, 0], to_target - reach, rtol=1e-9)
    np.testing.assert_allclose(np.cross(hand - base, targets[0] - base), 0.0, atol=1e-9)
    # Planted feet stay planted.
    np.testing.assert_allclose(res.residuals[0, 2:4], 0.0, atol=AdjustSettings().chain.tolerance)


def test_sub_base_passes_stop_at_their_fixed_point(rig):
    """With a target beyond reach (however the chest turns) the SC is re-placed only while a pass still moves
    the arm base by more than the reach margin (the most its best effort can gain), so a higher pass cap gives
    exactly the same pose; and the first pass alone is not that pose."""
    model, h, t, x = rig
    targets, _ = metarig.case(model, h, t, "far")
    few = _frames(rig, targets[None], None, settings=replace(AdjustSettings(), sub_base_passes=4))
    many = _frames(rig, targets[None], None, settings=replace(AdjustSettings(), sub_base_passes=12))
    np.testing.assert_array_equal(few.heads, many.heads)
    np.testing.assert_array_equal(few.rotations, many.rotations)
    assert few.iterations[0] == many.iterations[0]
    one = _frames(rig, targets[None], None, settings=replace(AdjustSettings(), sub_base_passes=1))
    assert not np.array_equal(one.heads, few.heads)
    arm = model.limbs["arm.L"].joints(h, t)
    reach = float(np.sum(np.linalg.norm(np.diff(arm, axis=0), axis=1)))
    assert few.residuals[0, 0] <= one.residuals[0, 0] + AdjustSettings().reach_margin * reach


def test_a_box_where_the_forearm_would_go_is_avoided(rig):
    model, h, t, x = rig
    base, boxes = metarig.case(model, h, t, "obstacle")
    arm = model.limbs["arm.L"]
    unobstructed = _frames(rig, base[None], None)
    free = arm.joints(unobstructed.heads[0], unobstructed.tails[0])
    assert segments_cross(free[:-1], free[1:], boxes).any()  # without the box the forearm would cross it
    res = _frames(rig, base[None], boxes)
    joints = arm.joints(res.heads[0], res.tails[0])
    assert res.status[0, 0] == "reached"
    assert not points_inside(joints, boxes).any()
    assert not segments_cross(joints[:-1], joints[1:], boxes).any()



def test_a_hand_the_held_trunk_cannot_bring_into_reach_reports_the_trunk(rig):
    """A spine held nearly straight (2 and 1 degree cones, given as the caller's limits: the default ones widen to
    the rest pose's own curve) and a hand target to the side that only a bending trunk would bring into reach:
    the trunk's chain ends limited, and a hand left short says so, with the trunk's status (on the batch's
    frames as when each pose is solved alone)."""
    model, h, t, x = rig
    height = float(np.ptp(np.concatenate([h, t])[:, 2]))

    def stiff(n):  # the default limits of n frames of the rest pose, the trunk's cones tightened
        limits = default_limits(model, np.repeat(h[None], n, 0), np.repeat(t[None], n, 0),
                                bone_x_axes=np.repeat(x[None], n, 0))
        trunk = limits["trunk"].limits.with_cone(0, np.radians(2.0))
        for i in range(1, len(trunk)):
            trunk = trunk.with_cone(i, np.radians(1.0))
        return {**limits, "trunk": LimbLimits(trunk, limits["trunk"].parent_direction)}

    base, _ = metarig.case(model, h, t, "near")
    targets = np.repeat(base[None], 3, axis=0)
    side = np.array([[-0.36, 0.53, 0.065], [0.51, 0.56, -0.285], [0.36, 0.51, -0.034]])  # in body heights
    targets[:, 0] = h[model.root] + side * height
    batch = _frames(rig, targets, None, limits=stiff(3))
    tol = AdjustSettings().chain.tolerance
    by_trunk = np.char.startswith(batch.reasons, "the trunk could not bring the SC into reach: ")
    assert by_trunk[:, :2].any(axis=1).all() and not by_trunk[:, 2:].any()  # hands only, on every frame
    assert np.all(batch.status[by_trunk] == "limited") and np.all(batch.residuals[by_trunk] > tol)
    assert np.all(batch.sc_displacement > 0.0)
    for f in range(len(targets)):
        alone = adjust_pose(model, h, t, targets[f], metarig.EFFECTORS, metarig.PRIORITIES, bone_x_axes=x,
                            limits=stiff(1))
        np.testing.assert_array_equal(alone.status, batch.status[f])
        np.testing.assert_array_equal(alone.reasons, batch.reasons[f])
