import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fullbody_adjust.solver import Boxes, ChainSettings, SolverInputError, penetrations
from fullbody_adjust.solver.chain.fabrik import solve_chain_batch
from fullbody_adjust.solver.limits.joint_limits import JointLimits, carry_axis
from fullbody_adjust.solver.obstacles.boxes import points_inside
from fullbody_adjust.solver.maths.geometry import any_perpendicular
from fullbody_adjust.solver.limits.joint_limits import CONE, HINGE

from .strategies import (boxes_corners, chains, lengths_of, reachable_targets, unit_vectors, unreachable_targets,
                         well_conditioned_targets)
from .one_chain import solve_chain

# A generous cap: FABRIK converges linearly and slowly for some folded poses; these tests are about where it
# ends, not how fast.
PATIENT = ChainSettings(max_iterations=3000)


def _segments(n):
    return np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)


def _assert_lengths_kept(start, result):
    np.testing.assert_allclose(lengths_of(result.positions), lengths_of(start), rtol=1e-9, atol=0)


# ---------------------------------------------------------------------------------------------------- basics


@settings(deadline=None, max_examples=400)
@given(st.data(), chains(min_joints=3))
def test_reachable_targets_are_met_and_lengths_kept(data, start):
    target = data.draw(well_conditioned_targets(start))
    result = solve_chain(start, target, settings=PATIENT)
    assert result.reachable
    assert result.status == "reached", result.reason
    assert result.residual <= PATIENT.tolerance
    assert np.linalg.norm(result.positions[-1] - target) == pytest.approx(result.residual, abs=1e-15)
    np.testing.assert_array_equal(result.positions[0], start[0])
    _assert_lengths_kept(start, result)


@settings(deadline=None, max_examples=200)
@given(st.data(), chains())
def test_unreachable_targets_stretch_the_chain_straight_toward_them(data, start):
    target = data.draw(unreachable_targets(start))
    result = solve_chain(start, target)
    total = lengths_of(start).sum()
    dist = np.linalg.norm(target - start[0])
    assert (result.status, result.reachable, result.iterations) == ("unreachable", False, 1)
    assert result.residual == pytest.approx(dist - total, rel=1e-9)
    # every joint on the ray base -> target, at its cumulative length
    u = (target - start[0]) / dist
    expected = start[0] + np.concatenate([[0.0], np.cumsum(lengths_of(start))])[:, None] * u
    np.testing.assert_allclose(result.positions, expected, atol=1e-9 * total)


def test_two_joint_chain_reaches_a_target_on_its_sphere_in_one_iteration():
    start = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    target = np.array([0.0, 0.6, 0.8])
    result = solve_chain(start, target)
    assert (result.status, result.iterations) == ("reached", 1)
    np.testing.assert_allclose(result.positions[1], target, atol=1e-12)


def test_already_met_target_takes_no_iteration_and_a_target_inside_the_fold_is_unreachable():
    start = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [3.0, 1.0, 0.0]])
    assert solve_chain(start, start[-1]).iterations == 0
    # a 3-long segment and a 1-long one cannot bring the end closer than 2 to the base
    result = solve_chain(start, np.array([0.5, 0.5, 0.0]))
    assert (result.status, result.reachable) == ("unreachable", False)
    assert result.residual == pytest.approx(2.0 - math.hypot(0.5, 0.5), abs=1e-4)


def test_iteration_cap_is_reported():
    start = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    result = solve_chain(start, np.array([0.3, 1.9, 0.4]), settings=ChainSettings(max_iterations=1))
    assert (result.status, result.iterations, result.reachable) == ("max_iterations", 1, True)
    assert result.residual > 1e-5


# ---------------------------------------------------------------------------------------------------- input


@pytest.mark.parametrize("positions, target, message", [
    ([[0, 0, 0], [1, 0, 0]], [np.nan, 0, 0], "target has NaN/inf"),
    ([[0, 0, 0], [np.inf, 0, 0]], [1, 0, 0], "positions have NaN/inf"),
    ([[0, 0, 0]], [1, 0, 0], "at least 2 joints"),
    ([[0, 0, 0], [1, 0, 0], [1, 0, 0]], [1, 0, 0], "segment 1 has zero length"),
    ([[0, 0], [1, 0]], [1, 0, 0], "shape"),
    ([[0, 0, 0], [1, 0, 0]], [1, 0], "shape"),
])
@pytest.mark.parametrize("obstacles", [None, Boxes(np.full((1, 3), 10.0), np.full((1, 3), 11.0))])
def test_bad_input_names_the_problem(positions, target, message, obstacles):
    kwargs = {"obstacles": obstacles}
    with pytest.raises(SolverInputError, match=message):
        solve_chain(np.array(positions, dtype=float), np.array(target, dtype=float), **kwargs)


def test_bad_settings_and_batch_shapes_are_rejected():
    with pytest.raises(SolverInputError, match="tolerance"):
        ChainSettings(tolerance=0.0)
    with pytest.raises(SolverInputError, match="max_iterations"):
        ChainSettings(max_iterations=0)
    with pytest.raises(SolverInputError, match="margin"):
        ChainSettings(margin=float("nan"))
    with pytest.raises(SolverInputError, match="targets must have shape"):
        solve_chain_batch(np.zeros((2, 3, 3)), np.zeros((3, 3)))
    start = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    with pytest.raises(SolverInputError, match="no parent_direction"):
        solve_chain(start, start[-1], limits=JointLimits.free(3).with_cone(0, 0.3))
    with pytest.raises(SolverInputError, match="limits cover"):
        solve_chain(start, start[-1], limits=JointLimits.free(4).with_cone(1, 0.3))


# ---------------------------------------------------------------------------------------------------- batch


@st.composite
def batch_problems(draw):
    """B problems on chains of one joint count, with mixed targets, optional limits and optional boxes."""
    n = draw(st.integers(3, 6))
    b = draw(st.integers(1, 5))
    starts, targets = [], []
    for _ in range(b):
        start = draw(chains(min_joints=n, max_joints=n))
        kind = draw(st.sampled_from(["reachable", "unreachable"]))
        target = draw(reachable_targets(start) if kind == "reachable" else unreachable_targets(start))
        starts.append(start)
        targets.append(target)
    limits = None
    if draw(st.booleans()):
        limits = JointLimits.free(n).with_cone(1, draw(st.floats(0.2, 2.5)))
    boxes = Boxes.from_corners(draw(boxes_corners(max_boxes=2))) if draw(st.booleans()) else None
    return np.array(starts), np.array(targets), limits, boxes


@settings(deadline=None, max_examples=80)
@given(batch_problems())
def test_batch_results_equal_single_results(problem):
    starts, targets, limits, boxes = problem
    batch = solve_chain_batch(starts, targets, limits=limits, obstacles=boxes)
    assert len(batch) == len(starts)
    for i in range(len(starts)):
        single = solve_chain(starts[i], targets[i], limits=limits, obstacles=boxes)
        np.testing.assert_allclose(batch.positions[i], single.positions, rtol=0, atol=1e-9)
        assert batch[i].status == single.status and batch[i].iterations == single.iterations
        assert batch[i].reason == single.reason


def test_per_problem_boxes_and_hinge_axes_pair_with_their_problem():
    start, target, boxes = _arm_past_a_box()
    starts = np.stack([start, start])
    targets = np.stack([target, target])
    # problem 0 has the box in the way, problem 1 has it far off
    mins = np.stack([boxes.mins, boxes.mins + 10.0])
    per_problem = Boxes(mins, mins + (boxes.maxs - boxes.mins))
    axes = np.array([[[0.0, 1.0, 0.0]] * 3, [[0.0, -1.0, 0.0]] * 3])
    limits = JointLimits.free(4).with_hinge(2, axes[:, 2], -2.0, 2.0)
    batch = solve_chain_batch(starts, targets, obstacles=per_problem, limits=limits)
    for i in range(2):
        single = solve_chain(start, target, obstacles=Boxes(per_problem.mins[i:i + 1], per_problem.maxs[i:i + 1]),
                             limits=JointLimits.free(4).with_hinge(2, axes[i, 2], -2.0, 2.0))
        np.testing.assert_allclose(batch.positions[i], single.positions, atol=1e-12)
    plain = solve_chain(start, target)
    assert sum(penetrations(batch.positions[0], _segments(4), boxes)) == 0
    assert batch.status[1] == "reached" and batch.status[0] == "reached", batch.reason
    assert not np.allclose(batch.positions[0], plain.positions)


# ---------------------------------------------------------------------------------------------------- limits


def _bend_angles(result_positions, start, limits, parent_direction):
    """Measured (cone angle, hinge out-of-plane, hinge bend) per limited joint, from the final pose, with the
    hinge axes carried the way the contract describes (from `limits.hinge_reference` if given). With a twist
    range the hinge plane is the one turned about the parent as near the child's plane as the range allows
    (both bend sides tried: the one the child is nearer to counts)."""
    out = []
    d = np.diff(result_positions, axis=0)
    d /= np.linalg.norm(d, axis=1)[:, None]
    d0 = np.diff(start, axis=0)
    d0 /= np.linalg.norm(d0, axis=1)[:, None]
    for i, kind in enumerate(limits.kind):
        parent = parent_direction if i == 0 else d[i - 1]
        child = d[i]
        if kind == CONE:
            out.append(("cone", i, math.atan2(np.linalg.norm(np.cross(parent, child)), parent @ child)))
        elif kind == HINGE:
            ref = d0[i - 1] if limits.hinge_reference is None else limits.hinge_reference[i]
            axis = limits.hinge_axis[i] if i == 0 else carry_axis(limits.hinge_axis[i], ref, parent)
            axis = axis - (axis @ parent) * parent
            axis /= np.linalg.norm(axis)
            side = np.cross(axis, parent)
            phi = math.atan2(child @ axis, child @ side)  # the child's azimuth about the parent
            best = None
            for plane in (phi, phi - math.pi if phi > 0 else phi + math.pi):
                tau = float(np.clip(plane, -limits.hinge_twist[i], limits.hinge_twist[i]))
                a = math.cos(tau) * axis - math.sin(tau) * side  # the axis turned by tau about the parent
                off = abs(child @ a)
                if best is None or off < best[0]:
                    best = (off, math.atan2(np.cross(parent, child) @ a, parent @ child))
            out.append(("hinge", i, best))
    return out


def _bend_in_range(bend, lo, hi):
    """A bend angle within [lo, hi] to 1e-9, modulo 2 pi (a full fold measures as pi or -pi)."""
    return any(lo - 1e-9 <= b <= hi + 1e-9 for b in (bend, bend - 2 * math.pi, bend + 2 * math.pi))


@st.composite
def limited_problems(draw):
    start = draw(chains(min_joints=3, max_joints=7))
    n = len(start)
    limits = JointLimits.free(n)
    parent_direction = draw(unit_vectors())
    d = np.diff(start, axis=0)
    d /= np.linalg.norm(d, axis=1)[:, None]
    for i in range(n - 1):
        kind = draw(st.sampled_from(["free", "cone", "hinge"]))
        if kind == "cone":
            limits = limits.with_cone(i, draw(st.floats(0.0, math.pi)))
        elif kind == "hinge":
            lo = draw(st.floats(-math.pi, math.pi))
            hi = draw(st.floats(lo, math.pi))
            axis = draw(unit_vectors())
            parent = parent_direction if i == 0 else d[i - 1]
            if np.linalg.norm(np.cross(axis, parent)) < 0.1:  # a hinge about its own parent bone is meaningless
                axis = any_perpendicular(parent)
            twist = draw(st.sampled_from([0.0, 0.0, 0.3, 1.4]))
            limits = limits.with_hinge(i, axis, lo, hi, twist)
    kind = draw(st.sampled_from(["reachable", "unreachable", "joint"]))
    if kind == "joint":
        target = start[draw(st.integers(0, n - 1))].copy()
    else:
        target = draw(reachable_targets(start) if kind == "reachable" else unreachable_targets(start))
    return start, target, limits, parent_direction


@settings(deadline=None, max_examples=200)
@given(limited_problems())
def test_limits_are_never_exceeded(problem):
    start, target, limits, parent_direction = problem
    result = solve_chain(start, target, limits=limits, parent_direction=parent_direction)
    assert np.all(np.isfinite(result.positions))
    _assert_lengths_kept(start, result)
    for what, i, value in _bend_angles(result.positions, start, limits, parent_direction):
        if what == "cone":
            assert value <= limits.cone_angle[i] + 1e-9
        else:
            off_plane, bend = value
            assert off_plane <= 1e-9
            assert _bend_in_range(bend, limits.hinge_min[i], limits.hinge_max[i]), (bend, limits)
    assert result.status in ("reached", "unreachable", "limited", "max_iterations")


def test_elbow_hinge_reaches_on_its_bend_side_and_refuses_the_other():
    # SC -> shoulder -> elbow -> wrist, elbow bent downward: positive bend = downward.
    start = np.array([[0.0, 0.0, 0.0], [0.15, 0.0, 0.0], [0.45, 0.0, 0.0], [0.65, 0.0, -0.18]])
    axis = _bend_axis(start)
    limits = JointLimits.free(4).with_hinge(2, axis, 0.0, 2.6)
    down = np.array([0.5, 0.0, -0.3])
    result = solve_chain(start, down, limits=limits, parent_direction=[1.0, 0.0, 0.0])
    assert result.status == "reached", result.reason
    # Straight up past the shoulder would need the elbow to bend backwards with the upper arm level.
    free_joints = JointLimits.free(4).with_cone(0, 1e-9).with_cone(1, 1e-9).with_hinge(2, axis, 0.0, 2.6)
    up = np.array([0.45 + 0.2 * math.cos(1.0), 0.0, 0.2 * math.sin(1.0)])
    result = solve_chain(start, up, limits=free_joints, parent_direction=[1.0, 0.0, 0.0])
    assert result.status == "limited"
    assert result.positions[3, 2] <= 1e-9  # the forearm stays on the downward side


def _valid_arm_pose(rng, start, axis0, spread, twist=0.0):
    """A pose of the arm of test_elbow_hinge... that satisfies its hinge: shoulder and upper arm directions
    perturbed by `spread`, the elbow bent about the carried axis turned by up to `twist` about the upper arm,
    by an angle in range."""
    lengths = np.linalg.norm(np.diff(start, axis=0), axis=1)
    dirs = np.diff(start, axis=0) / lengths[:, None]
    d0 = dirs[0] + rng.normal(size=3) * spread
    d1 = dirs[1] + rng.normal(size=3) * spread
    d0, d1 = d0 / np.linalg.norm(d0), d1 / np.linalg.norm(d1)
    axis = carry_axis(axis0, dirs[1], d1)
    axis = axis - (axis @ d1) * d1
    axis /= np.linalg.norm(axis)
    tau = rng.uniform(-twist, twist)
    axis = math.cos(tau) * axis - math.sin(tau) * np.cross(axis, d1)  # turned by tau about the upper arm
    bend = np.clip(0.73 + rng.normal() * 2 * spread, 0.0, 2.6)
    d2 = math.cos(bend) * d1 + math.sin(bend) * np.cross(axis, d1)
    return np.cumsum(np.vstack([start[:1], d0 * lengths[0], d1 * lengths[1], d2 * lengths[2]]), axis=0)


def test_hinged_arm_reaches_targets_of_nearby_valid_poses():
    start = np.array([[0.0, 0.0, 0.0], [0.15, 0.0, 0.0], [0.45, 0.0, 0.0], [0.65, 0.0, -0.18]])
    axis = _bend_axis(start)
    limits = JointLimits.free(4).with_cone(1, 1.5).with_hinge(2, axis, 0.0, 2.6)
    rng = np.random.default_rng(5)
    targets = np.array([_valid_arm_pose(rng, start, axis, 0.1)[-1] for _ in range(40)])
    results = solve_chain_batch(np.broadcast_to(start, (40, 4, 3)), targets, limits=limits,
                                parent_directions=np.tile([1.0, 0.0, 0.0], (40, 1)))
    assert list(results.status) == ["reached"] * 40
    for i in range(40):
        for what, j, value in _bend_angles(results.positions[i], start, limits, np.array([1.0, 0.0, 0.0])):
            if what == "hinge":
                assert value[0] <= 1e-9 and -1e-9 <= value[1] <= 2.6 + 1e-9


def _bend_axis(start):
    """The elbow's hinge axis that makes the start's bend positive: cross(upper arm, forearm), normalised."""
    axis = np.cross(start[2] - start[1], start[3] - start[2])
    return axis / np.linalg.norm(axis)


def _arm():
    start = np.array([[0.0, 0.0, 0.0], [0.15, 0.0, 0.0], [0.45, 0.0, 0.0], [0.65, 0.0, -0.18]])
    return start, _bend_axis(start), np.array([1.0, 0.0, 0.0])


def _assert_hinges_hold(positions, start, limits, parent_direction):
    for what, j, value in _bend_angles(positions, start, limits, parent_direction):
        if what == "hinge":
            assert value[0] <= 1e-9 and _bend_in_range(value[1], limits.hinge_min[j], limits.hinge_max[j])
        else:
            assert value <= limits.cone_angle[j] + 1e-9


def test_hinge_twist_reaches_targets_whose_bend_plane_turned_about_the_upper_arm():
    """Targets of valid poses whose elbow plane turned by up to 1 rad about the upper arm: a hinge allowed to
    turn 80 deg meets every one (its bend plane within the twist range); the plane carried by the swing alone
    cannot follow them all."""
    start, axis, pd = _arm()
    rng = np.random.default_rng(4)
    targets = np.array([_valid_arm_pose(rng, start, axis, 0.3, twist=1.0)[-1] for _ in range(60)])
    starts = np.broadcast_to(start, (60, 4, 3))
    pds = np.tile(pd, (60, 1))
    twisting = JointLimits.free(4).with_cone(1, 1.5).with_hinge(2, axis, 0.0, 2.6, twist=math.radians(80))
    results = solve_chain_batch(starts, targets, limits=twisting, parent_directions=pds)
    assert list(results.status) == ["reached"] * 60
    for i in range(60):
        _assert_hinges_hold(results.positions[i], start, twisting, pd)
    fixed = solve_chain_batch(starts, targets, limits=JointLimits.free(4).with_cone(1, 1.5).with_hinge(
        2, axis, 0.0, 2.6), parent_directions=pds)
    assert np.sum(fixed.status == "reached") < 60


def test_hinge_reference_carries_the_axis_from_the_given_direction():
    start, axis, pd = _arm()
    limits = JointLimits.free(4).with_cone(1, 1.5).with_hinge(2, axis, 0.0, 2.6, twist=0.5)
    target = np.array([0.35, 0.25, -0.2])
    # The default reference is the start pose's parent segment: giving it explicitly changes nothing.
    d0 = np.diff(start, axis=0)
    explicit = replace(limits, hinge_reference=np.vstack([d0[:1], d0[:-1]]))
    np.testing.assert_array_equal(solve_chain(start, target, limits=limits, parent_direction=pd).positions,
                                  solve_chain(start, target, limits=explicit, parent_direction=pd).positions)
    # A chain started from another pose (turned about its base) with the axis still given at `start`: the
    # result's hinge holds about the axis carried from the reference, not from the chain's own start.
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    turned = start @ turn.T
    result = solve_chain(turned, target, limits=explicit, parent_direction=pd)
    assert result.status == "reached", result.reason
    _assert_hinges_hold(result.positions, start, explicit, pd)
    with pytest.raises(SolverInputError, match="hinge reference"):
        solve_chain(start, target, limits=replace(limits, hinge_reference=np.zeros((3, 3))), parent_direction=pd)


def test_a_start_pose_at_its_target_is_returned_untouched_unless_it_breaks_a_limit():
    start, axis, pd = _arm()
    limits = JointLimits.free(4).with_cone(0, 0.5).with_cone(1, 1.5).with_hinge(2, axis, 0.0, 2.6, twist=0.5)
    far_box = Boxes(np.array([[5.0, 5.0, 5.0]]), np.array([[6.0, 6.0, 6.0]]))
    for kwargs in ({"limits": limits}, {"obstacles": far_box}, {"limits": limits, "obstacles": far_box}):
        result = solve_chain(start, start[-1], parent_direction=pd, **kwargs)
        assert result.status == "reached" and result.iterations == 0
        np.testing.assert_array_equal(result.positions, start)
    # The same pose against a hinge whose plane it is not in (90 deg off, no twist to make up for it):
    # iterated, and it comes out on the hinge.
    crooked = JointLimits.free(4).with_hinge(2, np.cross(axis, start[2] - start[1]), 0.0, 2.6)
    result = solve_chain(start, start[-1], limits=crooked, parent_direction=pd)
    assert result.iterations >= 1
    _assert_hinges_hold(result.positions, start, crooked, pd)
    # A box the start pose crosses: iterated too, and out of the box (or reported).
    box = Boxes(np.array([[0.25, -0.05, -0.05]]), np.array([[0.35, 0.05, 0.05]]))
    result = solve_chain(start, start[-1], obstacles=box, parent_direction=pd)
    assert result.iterations >= 1
    assert sum(penetrations(result.positions, _segments(4), box)) == 0 or result.status == "blocked"


@pytest.mark.parametrize("elbow", ["cone", "twisting hinge"])
def test_two_segment_finish_meets_targets_near_full_stretch_at_once(elbow):
    """Targets at 90 % of the reach in random forward directions: the last two segments are placed
    analytically as soon as the target is within their range (one iteration), where plain FABRIK creeps."""
    start, axis, pd = _arm()
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(100, 3))
    dirs[:, 0] = np.abs(dirs[:, 0]) + 0.5
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    targets = dirs * 0.9 * lengths_of(start).sum()
    limits = JointLimits.free(4).with_cone(0, 0.6).with_cone(1, 1.5)
    limits = limits.with_cone(2, 2.5) if elbow == "cone" else limits.with_hinge(2, axis, -0.2, 2.6, twist=1.4)
    results = solve_chain_batch(np.broadcast_to(start, (100, 4, 3)), targets, limits=limits,
                                parent_directions=np.tile(pd, (100, 1)))
    assert list(results.status) == ["reached"] * 100
    assert np.all(results.residual <= 1e-12)  # placed, not converged to within the tolerance
    assert np.mean(results.iterations) <= 1.5
    for i in range(100):
        _assert_lengths_kept(start, results[i])
        _assert_hinges_hold(results.positions[i], start, limits, pd)


def test_unreachable_target_with_a_hinge_still_stretches_toward_it():
    start = np.array([[0.0, 0.0, 0.0], [0.15, 0.0, 0.0], [0.45, 0.0, 0.0], [0.65, 0.0, -0.18]])
    axis = _bend_axis(start)
    limits = JointLimits.free(4).with_hinge(2, axis, 0.0, 2.6)
    target = np.array([3.0, 1.0, 0.5])
    result = solve_chain(start, target, limits=limits, parent_direction=[1.0, 0.0, 0.0])
    assert result.status == "unreachable"
    # the upper arm points at the target (its parent is free), the straight elbow is within [0, 2.6]
    upper = result.positions[2] - result.positions[1]
    to_target = target - result.positions[1]
    assert np.dot(upper, to_target) / (np.linalg.norm(upper) * np.linalg.norm(to_target)) == pytest.approx(1.0)
    assert result.residual == pytest.approx(np.linalg.norm(target) - lengths_of(start).sum(), rel=1e-9)


# ---------------------------------------------------------------------------------------------------- obstacles


@st.composite
def obstacle_problems(draw):
    start = draw(chains(min_joints=3, max_joints=6))
    corners = draw(boxes_corners(min_boxes=1, max_boxes=3, lo=-3.0, hi=3.0, max_size=1.0))
    boxes = Boxes.from_corners(corners)
    kind = draw(st.sampled_from(["reachable", "unreachable"]))
    target = draw(reachable_targets(start) if kind == "reachable" else unreachable_targets(start))
    return start, target, boxes


@settings(deadline=None, max_examples=200)
@given(obstacle_problems())
def test_no_penetration_unless_reported_blocked(problem):
    start, target, boxes = problem
    result = solve_chain(start, target, obstacles=boxes)
    assert np.all(np.isfinite(result.positions))
    _assert_lengths_kept(start, result)
    np.testing.assert_array_equal(result.positions[0], start[0])
    target_inside = points_inside(target, boxes).any()
    base_inside = points_inside(start[0], boxes).any()
    if target_inside:
        assert result.status == "blocked" and "target inside obstacle" in result.reason
    elif base_inside:
        assert result.status == "blocked" and "base inside obstacle" in result.reason
    else:
        inside, crossing = penetrations(result.positions, _segments(len(start)), boxes)
        if result.status != "blocked":
            assert inside == 0 and crossing == 0
        else:
            assert result.reason


def _arm_past_a_box():
    start = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.6, 0.0, 0.0], [0.9, 0.0, 0.0]])
    target = np.array([0.2, 0.0, 0.6])
    # a box between the straight arm and the target, where plain FABRIK folds the arm through
    boxes = Boxes(np.array([[0.25, -0.2, 0.15]]), np.array([[0.45, 0.2, 0.35]]))
    return start, target, boxes


def test_obstacle_avoided_where_plain_fabrik_goes_through():
    start, target, boxes = _arm_past_a_box()
    plain = solve_chain(start, target)
    assert sum(penetrations(plain.positions, _segments(4), boxes)) > 0  # the scene is a real test
    ours = solve_chain(start, target, obstacles=boxes)
    assert ours.status == "reached", ours.reason
    assert sum(penetrations(ours.positions, _segments(4), boxes)) == 0
    # the joints keep clear of the box by more than nothing (the response adds the margin Δd)
    assert not points_inside(ours.positions, Boxes(boxes.mins - 1e-4, boxes.maxs + 1e-4)).any()


def test_target_inside_an_obstacle_is_a_defined_result():
    start, _, boxes = _arm_past_a_box()
    target = np.array([0.35, 0.0, 0.25])  # the box's centre
    result = solve_chain(start, target, obstacles=boxes)
    assert result.status == "blocked" and "target inside obstacle" in result.reason
    assert result.residual <= 1e-5  # the end joint and last segment may enter that box
    inside = points_inside(result.positions[:-1], boxes)
    assert not inside.any()


def test_obstacles_as_corner_arrays_and_bad_obstacles():
    start, target, boxes = _arm_past_a_box()
    corners = np.stack([boxes.mins, boxes.maxs], axis=1)
    np.testing.assert_array_equal(solve_chain(start, target, obstacles=corners).positions,
                                  solve_chain(start, target, obstacles=boxes).positions)
    with pytest.raises(SolverInputError, match="corners have NaN/inf"):
        solve_chain(start, target, obstacles=np.full((1, 8, 3), np.nan))
    with pytest.raises(SolverInputError, match="obstacles must be"):
        solve_chain(start, target, obstacles="table")


def test_empty_obstacles_and_free_limits_equal_none():
    start, target, _ = _arm_past_a_box()
    plain = solve_chain(start, target)
    for kwargs in ({"obstacles": Boxes.empty()}, {"obstacles": np.zeros((0, 8, 3))},
                   {"limits": JointLimits.free(4)}):
        other = solve_chain(start, target, **kwargs)
        np.testing.assert_array_equal(other.positions, plain.positions)
