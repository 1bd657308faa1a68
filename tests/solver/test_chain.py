import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fullbody_adjust.solver import (Boxes, ChainSettings, JointLimits, SolverInputError, carry_axis,
                                    hinge_axis_from_bend, penetrations, points_inside, solve_chain,
                                    solve_chain_batch)
from fullbody_adjust.solver.geometry import any_perpendicular
from fullbody_adjust.solver.limits import CONE, HINGE

from .strategies import (boxes_corners, chains, lengths_of, reachable_targets, unit_vectors, unreachable_targets,
                         well_conditioned_targets)

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


@settings(deadline=None, max_examples=300)
@given(st.data(), chains(), st.sampled_from(["reachable", "unreachable", "joint"]))
def test_plain_and_numpy_paths_agree(data, start, kind):
    if kind == "joint":  # aim at one of the chain's own joints: coincident joints during the passes
        target = start[data.draw(st.integers(0, len(start) - 1))].copy()
    elif kind == "reachable" and len(start) > 2:
        target = data.draw(reachable_targets(start))
    else:
        target = data.draw(unreachable_targets(start))
    plain = solve_chain(start, target)
    batch = solve_chain_batch(start[None], target[None])[0]
    np.testing.assert_allclose(batch.positions, plain.positions, rtol=0, atol=1e-9)
    assert (batch.iterations, batch.status, batch.reachable) == (plain.iterations, plain.status, plain.reachable)
    assert batch.residual == pytest.approx(plain.residual, abs=1e-9)
    assert np.all(np.isfinite(plain.positions))


# ---------------------------------------------------------------------------------------------------- input


@pytest.mark.parametrize("positions, target, message", [
    ([[0, 0, 0], [1, 0, 0]], [np.nan, 0, 0], "target has NaN/inf"),
    ([[0, 0, 0], [np.inf, 0, 0]], [1, 0, 0], "positions have NaN/inf"),
    ([[0, 0, 0]], [1, 0, 0], "at least 2 joints"),
    ([[0, 0, 0], [1, 0, 0], [1, 0, 0]], [1, 0, 0], "segment 1 has zero length"),
    ([[0, 0], [1, 0]], [1, 0, 0], "shape"),
    ([[0, 0, 0], [1, 0, 0]], [1, 0], "shape"),
])
@pytest.mark.parametrize("path", ["plain", "numpy"])
def test_bad_input_names_the_problem(positions, target, message, path):
    kwargs = {} if path == "plain" else {"obstacles": Boxes(np.full((1, 3), 10.0), np.full((1, 3), 11.0))}
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


# ---------------------------------------------------------------------------------------------------- limits


def _bend_angles(result_positions, start, limits, parent_direction):
    """Measured (cone angle, hinge out-of-plane, hinge bend) per limited joint, from the final pose, with the
    hinge axes carried the way the contract describes."""
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
            axis = limits.hinge_axis[i] if i == 0 else carry_axis(limits.hinge_axis[i], d0[i - 1], parent)
            axis = axis - (axis @ parent) * parent
            axis /= np.linalg.norm(axis)
            bend = math.atan2(np.cross(parent, child) @ axis, parent @ child)
            out.append(("hinge", i, (abs(child @ axis), bend)))
    return out


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
            limits = limits.with_hinge(i, axis, lo, hi)
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
            assert limits.hinge_min[i] - 1e-9 <= bend <= limits.hinge_max[i] + 1e-9
    assert result.status in ("reached", "unreachable", "limited", "max_iterations")


def test_elbow_hinge_reaches_on_its_bend_side_and_refuses_the_other():
    # SC -> shoulder -> elbow -> wrist, elbow bent downward: positive bend = downward.
    start = np.array([[0.0, 0.0, 0.0], [0.15, 0.0, 0.0], [0.45, 0.0, 0.0], [0.65, 0.0, -0.18]])
    axis = hinge_axis_from_bend(start[2] - start[1], start[3] - start[2])
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


def _valid_arm_pose(rng, start, axis0, spread):
    """A pose of the arm of test_elbow_hinge... that satisfies its hinge: shoulder and upper arm directions
    perturbed by `spread`, the elbow bent about the carried axis by an angle in range."""
    lengths = np.linalg.norm(np.diff(start, axis=0), axis=1)
    dirs = np.diff(start, axis=0) / lengths[:, None]
    d0 = dirs[0] + rng.normal(size=3) * spread
    d1 = dirs[1] + rng.normal(size=3) * spread
    d0, d1 = d0 / np.linalg.norm(d0), d1 / np.linalg.norm(d1)
    axis = carry_axis(axis0, dirs[1], d1)
    axis = axis - (axis @ d1) * d1
    axis /= np.linalg.norm(axis)
    bend = np.clip(0.73 + rng.normal() * 2 * spread, 0.0, 2.6)
    d2 = math.cos(bend) * d1 + math.sin(bend) * np.cross(axis, d1)
    return np.cumsum(np.vstack([start[:1], d0 * lengths[0], d1 * lengths[1], d2 * lengths[2]]), axis=0)


def test_hinged_arm_reaches_targets_of_nearby_valid_poses():
    start = np.array([[0.0, 0.0, 0.0], [0.15, 0.0, 0.0], [0.45, 0.0, 0.0], [0.65, 0.0, -0.18]])
    axis = hinge_axis_from_bend(start[2] - start[1], start[3] - start[2])
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


def test_unreachable_target_with_a_hinge_still_stretches_toward_it():
    start = np.array([[0.0, 0.0, 0.0], [0.15, 0.0, 0.0], [0.45, 0.0, 0.0], [0.65, 0.0, -0.18]])
    axis = hinge_axis_from_bend(start[2] - start[1], start[3] - start[2])
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
    # margin: every joint keeps at least... it is outside the box
    assert not points_inside(ours.positions, boxes).any()


def test_target_inside_an_obstacle_is_a_defined_result():
    start, _, boxes = _arm_past_a_box()
    target = np.array([0.35, 0.0, 0.25])  # the box's centre
    result = solve_chain(start, target, obstacles=boxes)
    assert result.status == "blocked" and "target inside obstacle" in result.reason
    assert result.residual <= 1e-5  # the end joint and last segment may enter that box
    inside = points_inside(result.positions[:-1], boxes)
    assert not inside.any()


def test_empty_obstacles_and_free_limits_take_the_plain_path_result():
    start, target, _ = _arm_past_a_box()
    plain = solve_chain(start, target)
    for kwargs in ({"obstacles": Boxes.empty()}, {"limits": JointLimits.free(4)}):
        other = solve_chain(start, target, **kwargs)
        np.testing.assert_array_equal(other.positions, plain.positions)
