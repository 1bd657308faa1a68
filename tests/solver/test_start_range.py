"""A start pose outside the default joint ranges is the rig's own range there (solver/limits/start_range.py): a limb that
need not move keeps it bit for bit, with joint limits on as with them off, and a limb that moves is not pulled
back into the default range. Poses are the Rigify metarig's rest with a leg raised past the default hip cone
and elbows folded past the default hinge range; expectations are computed here from the joints."""

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver.fullbody.adjust import AdjustSettings, adjust_pose
from fullbody_adjust.solver.limits.human import HumanLimits, default_limits
from fullbody_adjust.solver.limits.joint_limits import CONE, FREE, HINGE
from fullbody_adjust.solver.limits.start_range import widened_ranges
from tests.helpers import metarig
from tests.helpers.rotations import about_axis

HUMAN = HumanLimits()


@pytest.fixture(scope="module")
def rig():
    return metarig.load()


def _subtree(model, bone):
    """bone and every bone below it."""
    out = {bone}
    for j in model.order.tolist():
        if model.parents[j] in out:
            out.add(j)
    return sorted(out)


def _turned(model, heads, tails, bone, axis, angle):
    """heads, tails with `bone` and everything below it turned by `angle` about `axis` through its head."""
    heads, tails = heads.copy(), tails.copy()
    turn = about_axis(axis, angle)
    pivot = heads[bone].copy()
    below = _subtree(model, bone)
    heads[below] = (heads[below] - pivot) @ turn.T + pivot
    tails[below] = (tails[below] - pivot) @ turn.T + pivot
    return heads, tails


def _bend(joints):
    """Angle (radians) between the last two segments of a chain's joints (n,3)."""
    u, v = joints[-2] - joints[-3], joints[-1] - joints[-2]
    return math.atan2(np.linalg.norm(np.cross(u, v)), float(u @ v))


def _folded(model, heads, tails, limb, bend):
    """The limb's elbow or knee folded (in its own bend plane) to `bend` radians."""
    joints = model.limbs[limb].joints(heads, tails)
    u, v = joints[-2] - joints[-3], joints[-1] - joints[-2]
    axis = np.cross(u, v)
    return _turned(model, heads, tails, model.limbs[limb].bones[-1], axis / np.linalg.norm(axis),
                   bend - _bend(joints))


def _outside_pose(rig):
    """The metarig with its left leg raised 125 degrees forward (its hip past the default 115 degree cone) and both
    elbows folded to 2.95 rad (past the default 2.7)."""
    model, h, t, _x = rig
    up, left, forward = (a[0] for a in model.body_frame(h[None], t[None]))
    heads, tails = _turned(model, h, t, model.limbs["leg.L"].bones[0], left, -math.radians(125.0))
    for arm in ("arm.L", "arm.R"):
        heads, tails = _folded(model, heads, tails, arm, 2.95)
    leg = model.limbs["leg.L"].joints(heads, tails)
    hip_angle = math.acos(np.clip(-up @ (leg[1] - leg[0]) / np.linalg.norm(leg[1] - leg[0]), -1.0, 1.0))
    assert hip_angle > HUMAN.hip + 0.1  # the start lies outside the default ranges
    assert _bend(model.limbs["arm.R"].joints(heads, tails)) > HUMAN.elbow[1] + 0.2
    return heads, tails


def _solve(rig, heads, tails, targets, use_limits=True):
    model, _h, _t, x = rig
    return adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, bone_x_axes=x,
                       settings=replace(AdjustSettings(), use_limits=use_limits))


def test_limbs_that_need_not_move_keep_a_start_outside_the_default_ranges(rig):
    """The right hand moved within its arm's reach, every other effector targeted where it stands: only the right
    arm's bones turn; every other bone keeps its head, tail and rotation bit for bit, limits on as off."""
    model, _h, _t, _x = rig
    heads, tails = _outside_pose(rig)
    targets = metarig.wrists_and_ankles(model, heads)
    arm = model.limbs["arm.R"].joints(heads, tails)
    targets[1] = arm[-1] + 0.2 * (arm[0] - arm[-1])  # toward the shoulder: within reach
    moving = set(model.limbs["arm.R"].bones) | set(_subtree(model, model.limbs["arm.R"].end_bone))
    others = [j for j in range(len(model.names)) if j not in moving]
    for use_limits in (True, False):
        res = _solve(rig, heads, tails, targets, use_limits)
        assert res.status[1] == "reached"
        np.testing.assert_array_equal(res.heads[others], heads[others])
        np.testing.assert_array_equal(res.tails[others], tails[others])
        np.testing.assert_array_equal(res.rotations[others], np.broadcast_to(np.eye(3), (len(others), 3, 3)))
        turned = [j for j in moving if not np.array_equal(res.rotations[j], np.eye(3))]
        assert set(turned) <= set(model.limbs["arm.R"].bones) and turned


def test_a_limb_that_moves_is_not_pulled_back_into_the_default_range(rig):
    """The right elbow starts folded past the default hinge range and its hand moves a little: the solved elbow
    stays folded about as far as it started (the old limits pulled it back to 2.7 rad), never further."""
    model, _h, _t, _x = rig
    heads, tails = _outside_pose(rig)
    arm = model.limbs["arm.R"]
    start_bend = _bend(arm.joints(heads, tails))
    targets = metarig.wrists_and_ankles(model, heads)
    up, left, forward = (a[0] for a in model.body_frame(heads[None], tails[None]))
    height = float(np.ptp(np.concatenate([heads, tails])[:, 2]))
    for offset in (0.01 * forward, 0.01 * up, -0.01 * left):
        targets[1] = arm.joints(heads, tails)[-1] + offset * height
        res = _solve(rig, heads, tails, targets)
        assert res.status[1] == "reached"
        bend = _bend(arm.joints(res.heads, res.tails))
        assert HUMAN.elbow[1] + 0.1 < bend <= start_bend + 1e-9


@settings(deadline=None, max_examples=40)
@given(dirs=arrays(np.float64, (3, 4, 3), elements=st.floats(-1.0, 1.0)),
       axis=arrays(np.float64, (3, 3), elements=st.floats(-1.0, 1.0)),
       cones=st.tuples(st.floats(0.0, 3.0), st.floats(0.0, 3.0)), hinge=st.tuples(st.floats(-1.0, 0.0),
                                                                                   st.floats(0.0, 2.0)))
def test_ranges_widen_exactly_to_the_widest_start_and_never_narrow(dirs, axis, cones, hinge):
    """Joint 0 a cone about a parent direction, joint 1 a cone, joint 2 a hinge, joint 3 free, over three frames:
    each bound is the given one or, where a frame's start lies beyond it, that start's angle (the widest)."""
    segments, parent = dirs[:, 1:], dirs[:, 0]
    if np.any(np.linalg.norm(dirs, axis=-1) < 1e-3) or np.any(np.linalg.norm(axis, axis=-1) < 1e-3):
        return
    kind = np.array([CONE, CONE, HINGE])
    cone, lo, hi = np.array([cones[0], cones[1], math.pi]), np.full(3, -math.pi), np.full(3, math.pi)
    lo[2], hi[2] = hinge
    axes = np.zeros((3, 3, 3))
    axes[:, 2] = axis
    wide_cone, wide_lo, wide_hi = widened_ranges(kind, cone, lo, hi, axes, parent, segments)

    def angle(a, b):
        return np.arccos(np.clip(np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1), -1, 1))

    for i, p in ((0, parent), (1, segments[:, 0])):
        start = angle(p, segments[:, i]).max()
        assert wide_cone[i] == pytest.approx(max(cone[i], start), abs=1e-7) and wide_cone[i] >= cone[i]
    # The hinge: the bend is the angle between the segments, on the side of the hinge plane the child lies on.
    u, v = segments[:, 1], segments[:, 2]
    a = axis - np.sum(axis * u, -1)[:, None] * u / np.sum(u * u, -1)[:, None]
    if np.any(np.linalg.norm(a, axis=-1) < 1e-3 * np.linalg.norm(axis, axis=-1)):
        return  # an axis along the parent: the hinge has no plane
    across = np.sum(v * np.cross(a, u), -1)
    if np.any(np.abs(across) < 1e-9 * np.linalg.norm(v, axis=-1) * np.linalg.norm(np.cross(a, u), axis=-1)):
        return  # a child in the plane of the axis and the parent: its bend is either side's (Hypothesis found one)
    side = across >= 0.0
    bends = np.where(side, 1.0, -1.0) * angle(u, v)
    assert wide_hi[2] == pytest.approx(max(hi[2], bends[side].max(initial=-math.pi)), abs=1e-7)
    assert wide_lo[2] == pytest.approx(min(lo[2], bends[~side].min(initial=math.pi)), abs=1e-7)
    assert wide_cone[2] == cone[2] and list(wide_lo[:2]) == list(lo[:2]) and list(wide_hi[:2]) == list(hi[:2])


def test_a_free_joint_and_a_joint_0_without_parent_direction_stay_as_given():
    segments = np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    kind = np.array([CONE, FREE])
    cone, lo, hi = np.array([0.1, 0.2]), np.full(2, -0.5), np.full(2, 0.5)
    out = widened_ranges(kind, cone, lo, hi, np.zeros((1, 2, 3)), None, segments)
    for got, given_ in zip(out, (cone, lo, hi)):
        np.testing.assert_array_equal(got, given_)


def test_default_limits_hold_the_start_of_every_frame(rig):
    """Two frames, one inside the defaults and one outside: the ranges widen to the wider start, once."""
    model, h, t, x = rig
    heads, tails = _outside_pose(rig)
    limits = default_limits(model, np.stack([h, heads]), np.stack([t, tails]), HUMAN, np.stack([x, x]))
    elbow = len(model.limbs["arm.R"].bones) - 1
    assert limits["arm.R"].limits.hinge_max[elbow] == pytest.approx(2.95, abs=1e-7)
    alone = default_limits(model, h[None], t[None], HUMAN, x[None])
    assert alone["arm.R"].limits.hinge_max[elbow] == HUMAN.elbow[1]
    assert limits["leg.L"].limits.cone_angle[0] > HUMAN.hip + 0.1 and alone["leg.L"].limits.cone_angle[0] == HUMAN.hip


def test_a_straight_leg_on_its_target_stays_however_its_reach_rounds(rig):
    """A leg straightened exactly, its ankle target half the tolerance beyond the ankle along the leg (past the
    sum of its lengths, as rounding can put a straight leg's own ankle): the target is met where it stands, so
    the pelvis stays and only the right arm moves for a near right-hand target."""
    model, h, t, _x = rig
    leg = model.limbs["leg.L"]
    joints = leg.joints(h, t)
    u, v = joints[1] - joints[0], joints[2] - joints[1]
    axis = np.cross(v, u)
    heads, tails = _turned(model, h, t, leg.bones[-1], axis, math.atan2(np.linalg.norm(axis), u @ v))
    joints = leg.joints(heads, tails)
    assert _bend(joints) < 1e-9
    targets = metarig.wrists_and_ankles(model, heads)
    tol = AdjustSettings().chain.tolerance
    targets[2] = joints[-1] + 0.5 * tol * (joints[-1] - joints[0]) / np.linalg.norm(joints[-1] - joints[0])
    assert np.linalg.norm(targets[2] - joints[0]) > np.linalg.norm(np.diff(joints, axis=0), axis=1).sum()
    arm = model.limbs["arm.R"].joints(heads, tails)
    targets[1] = arm[-1] + 0.2 * (arm[0] - arm[-1])
    res = _solve(rig, heads, tails, targets)
    assert res.root_displacement == 0.0 and res.status[2] == "reached"
    moving = set(model.limbs["arm.R"].bones) | set(_subtree(model, model.limbs["arm.R"].end_bone))
    others = [j for j in range(len(model.names)) if j not in moving]
    np.testing.assert_array_equal(res.heads[others], heads[others])
    np.testing.assert_array_equal(res.rotations[others], np.broadcast_to(np.eye(3), (len(others), 3, 3)))
