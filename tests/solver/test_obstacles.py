from fractions import Fraction

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver import Boxes, SolverInputError, penetrations
from fullbody_adjust.solver.obstacles.boxes import as_boxes, points_inside, segments_cross

from .strategies import boxes_corners

points3 = arrays(np.float64, 3, elements=st.floats(-5.0, 5.0))


def _exact_overlap(a, b, lo, hi):
    """t_exit - t_enter of segment a-b through the box, in exact rational arithmetic (Liang-Barsky):
    >= 0 iff the closed segment meets the closed box."""
    t_enter, t_exit = Fraction(0), Fraction(1)
    for c in range(3):
        ac, d = Fraction(a[c]), Fraction(b[c]) - Fraction(a[c])
        lc, hc = Fraction(lo[c]), Fraction(hi[c])
        if d == 0:
            if not lc <= ac <= hc:
                return Fraction(-1)
            continue
        t1, t2 = (lc - ac) / d, (hc - ac) / d
        t_enter, t_exit = max(t_enter, min(t1, t2)), min(t_exit, max(t1, t2))
    return t_exit - t_enter


def test_from_corners_takes_min_and_max_of_eight_corners():
    rng = np.random.default_rng(1)
    corners = rng.normal(size=(3, 8, 3))
    boxes = Boxes.from_corners(corners)
    np.testing.assert_array_equal(boxes.mins, corners.min(axis=1))
    np.testing.assert_array_equal(boxes.maxs, corners.max(axis=1))
    assert len(boxes) == 3
    assert boxes.corners().shape == (3, 8, 3)
    np.testing.assert_array_equal(boxes.corners().min(axis=1), boxes.mins)


def test_empty_boxes_and_per_problem_boxes():
    assert len(Boxes.empty()) == 0
    assert len(as_boxes(np.zeros((0, 8, 3)))) == 0 and as_boxes(None) is None
    assert points_inside(np.zeros((4, 3)), Boxes.empty()).shape == (4, 0)
    per_problem = Boxes.from_corners(np.zeros((5, 2, 2, 3)) + np.array([0.0, 1.0])[None, None, :, None])
    assert per_problem.batched and len(per_problem) == 2


@pytest.mark.parametrize("corners, message", [
    (np.full((1, 8, 3), np.nan), "NaN/inf"),
    (np.zeros((1, 3)), "shape"),
])
def test_bad_corners_are_rejected(corners, message):
    with pytest.raises(SolverInputError, match=message):
        Boxes.from_corners(corners)


def test_min_above_max_is_rejected():
    with pytest.raises(SolverInputError, match="box 1 has min > max"):
        Boxes(np.zeros((2, 3)), np.array([[1.0, 1.0, 1.0], [1.0, -1.0, 1.0]]))


@settings(deadline=None, max_examples=200)
@given(st.lists(points3, min_size=1, max_size=6), boxes_corners(min_boxes=1))
def test_points_inside_matches_a_per_coordinate_check(points, corners):
    boxes = Boxes.from_corners(corners)
    pts = np.array(points)
    got = points_inside(pts, boxes)
    for i, p in enumerate(pts):
        for k in range(len(boxes)):
            expected = all(boxes.mins[k, c] <= p[c] <= boxes.maxs[k, c] for c in range(3))
            assert got[i, k] == expected


@settings(deadline=None, max_examples=400)
@given(points3, points3, boxes_corners(min_boxes=1, max_boxes=1, lo=-3.0, hi=2.0))
def test_segments_cross_matches_exact_arithmetic(a, b, corners):
    boxes = Boxes.from_corners(corners)
    overlap = _exact_overlap(a, b, boxes.mins[0], boxes.maxs[0])
    assume(abs(overlap) > 1e-9)  # grazing contacts are decided by rounding
    assert bool(segments_cross(a, b, boxes)[0]) == (overlap > 0)


def test_segments_cross_axis_parallel_and_degenerate_segments():
    boxes = Boxes(np.array([[0.0, 0.0, 0.0]]), np.array([[1.0, 1.0, 1.0]]))
    a = np.array([[-1.0, 0.5, 0.5], [-1.0, 1.5, 0.5], [0.5, 0.5, 0.5], [2.0, 2.0, 2.0]])
    b = np.array([[2.0, 0.5, 0.5], [2.0, 1.5, 0.5], [0.5, 0.5, 0.5], [2.0, 2.0, 2.0]])
    np.testing.assert_array_equal(segments_cross(a, b, boxes)[:, 0], [True, False, True, False])


def test_per_problem_boxes_pair_with_the_batch_axis():
    mins = np.array([[[0.0, 0.0, 0.0]], [[5.0, 5.0, 5.0]]])
    boxes = Boxes(mins, mins + 1.0)
    pts = np.array([[[0.5, 0.5, 0.5], [5.5, 5.5, 5.5]], [[0.5, 0.5, 0.5], [5.5, 5.5, 5.5]]])
    np.testing.assert_array_equal(points_inside(pts, boxes)[..., 0], [[True, False], [False, True]])
    seg = segments_cross(pts[:, 0], pts[:, 1], boxes)
    np.testing.assert_array_equal(seg[:, 0], [True, True])


def test_penetrations_counts_joints_and_segments():
    boxes = Boxes(np.array([[0.0, -1.0, -1.0]]), np.array([[1.0, 1.0, 1.0]]))
    positions = np.array([[-1.0, 0.0, 0.0], [0.5, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    inside, crossing = penetrations(positions, [[0, 1], [1, 2], [2, 3]], boxes)
    assert (int(inside), int(crossing)) == (1, 2)
    inside, crossing = penetrations(positions[None].repeat(3, axis=0), [[0, 2]], boxes)
    np.testing.assert_array_equal(inside, [1, 1, 1])
    np.testing.assert_array_equal(crossing, [1, 1, 1])
    inside, crossing = penetrations(positions, [[0, 1]], Boxes.empty())
    assert (int(inside), int(crossing)) == (0, 0)


@pytest.mark.parametrize("oriented", [False, True])
@pytest.mark.parametrize("per_problem", [False, True])
def test_one_anchor_with_many_ends_equals_the_anchor_repeated(oriented, per_problem):
    """segments_cross of anchors (b,1,3) to candidates (b,c,3), as the obstacle response asks it, gives what the
    anchors repeated to (b,c,3) give, also for candidates level with the anchor along an axis (a step of 0) or a hair
    off it (a step of 1e-300, where the quotients overflow)."""
    rng = np.random.default_rng(7)
    b, c, k = 3, 40, 2
    anchors = rng.uniform(-1.0, 1.0, (b, 1, 3))
    ends = anchors + rng.uniform(-1.5, 1.5, (b, c, 3))
    ends[:, :10, 0] = anchors[:, :, 0]  # level along x
    ends[:, 10:20, 1] = anchors[:, :, 1] + 1e-300
    centres = rng.uniform(-0.8, 0.8, (b, k, 3) if per_problem else (k, 3))
    half = rng.uniform(0.1, 0.6, centres.shape)
    axes = None
    if oriented:
        q, _ = np.linalg.qr(rng.normal(size=centres.shape[:-1] + (3, 3)))
        axes = q
    boxes = Boxes(centres - half, centres + half, axes)
    with np.errstate(all="raise"):  # the overflowing quotients stay quiet
        one = segments_cross(anchors, ends, boxes)
    repeated = segments_cross(np.repeat(anchors, c, axis=1), ends, boxes)
    np.testing.assert_array_equal(one, repeated)
    assert one.any() and not one.all()
