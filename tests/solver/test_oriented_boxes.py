"""Oriented obstacle boxes: a box with its own axes is tested in its own frame, and a chain keeps out of it
without avoiding the corners its axis-aligned box would add."""

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver import Boxes, SolverInputError, penetrations
from fullbody_adjust.solver.obstacles.boxes import points_inside, segments_cross
from tests.helpers.rotations import about_axis
from .one_chain import solve_chain

# Corner i of Blender's bound_box: x from bit 2, y from (i in 2,3,6,7), z from (i in 1,2,5,6).
_BOUND_BOX_SIGNS = np.array([[-1, -1, -1], [-1, -1, 1], [-1, 1, 1], [-1, 1, -1],
                             [1, -1, -1], [1, -1, 1], [1, 1, 1], [1, 1, -1]], dtype=np.float64)


def _box_corners(centre, rotation, half):
    """World corners (8,3), bound_box order, of a box with these centre, rotation and half sizes."""
    return centre + (_BOUND_BOX_SIGNS * half) @ rotation.T


points3 = arrays(np.float64, 3, elements=st.floats(-3.0, 3.0))
unit3 = arrays(np.float64, 3, elements=st.floats(-1.0, 1.0))


@settings(deadline=None, max_examples=200)
@given(st.lists(points3, min_size=1, max_size=5), unit3, st.floats(-np.pi, np.pi), unit3,
       arrays(np.float64, 3, elements=st.floats(0.1, 1.5)))
@example(points=[np.array([1.0, 1.0, 1.5])], axis=np.array([1.0, 0.0, 0.0]), angle=-9.401572611590432e-07,
         centre=np.zeros(3), half=np.full(3, 1.5))  # on a face of a box turned by less than the tolerance
def test_inside_and_crossing_are_the_axis_aligned_tests_in_the_box_frame(points, axis, angle, centre, half):
    assume(np.linalg.norm(axis) > 0.1)
    rotation = about_axis(axis, angle)
    box = Boxes.from_box_corners(_box_corners(centre, rotation, half)[None])
    unrotated = Boxes((-half)[None], half[None])  # the same box before its rotation, about its centre
    pts = np.array(points)
    local = (pts - centre) @ rotation  # rotation.T @ (p - centre)
    # Points closer than rounding to a face are decided either way; a box turned by less than the axis-aligned
    # tolerance (boxes._ALIGNED, 1e-6 per axis component) is tested as the axis-aligned box around its corners,
    # which reaches past its faces by up to that tolerance times its size.
    margin = np.min(np.abs(np.abs(local) - half), axis=-1)
    keep = margin > (1e-9 if box.axes is not None else 1e-9 + 4e-6 * float(half.sum()))
    np.testing.assert_array_equal(points_inside(pts, box)[keep], points_inside(local, unrotated)[keep])
    if len(pts) >= 2:
        got = segments_cross(pts[:-1], pts[1:], box)[:, 0]
        expected = segments_cross(local[:-1], local[1:], unrotated)[:, 0]
        near = Boxes((-half - 1e-7)[None], (half + 1e-7)[None])
        shrunk = Boxes((-half + 1e-7)[None], (half - 1e-7)[None])
        decided = segments_cross(local[:-1], local[1:], near)[:, 0] == segments_cross(local[:-1], local[1:],
                                                                                      shrunk)[:, 0]
        np.testing.assert_array_equal(got[decided], expected[decided])


def test_corners_come_back_and_an_unrotated_box_stays_axis_aligned():
    rotation = about_axis([1.0, 2.0, 0.5], 0.7)
    corners = _box_corners(np.array([0.3, -1.0, 2.0]), rotation, np.array([0.5, 1.0, 0.2]))
    box = Boxes.from_box_corners(corners[None])
    assert box.oriented
    # The box's corners are the given ones, in some order.
    got = box.corners()[0]
    assert np.max(np.min(np.linalg.norm(got[:, None] - corners[None], axis=-1), axis=0)) < 1e-12
    quarter = about_axis([0.0, 0.0, 1.0], np.pi / 2)
    plain = Boxes.from_box_corners(_box_corners(np.zeros(3), quarter, np.array([1.0, 2.0, 3.0]))[None])
    assert not plain.oriented
    np.testing.assert_allclose(plain.mins, [[-2.0, -1.0, -3.0]], atol=1e-12)
    np.testing.assert_allclose(plain.maxs, [[2.0, 1.0, 3.0]], atol=1e-12)


def test_a_box_turned_by_rounding_is_axis_aligned_and_one_turned_more_is_not():
    """A mesh's box through a glTF armature's quarter turn in float32 is off the axes by about 1e-7: the fast
    axis-aligned tests take it, its bounds those of its corners (within a millionth of its size of the box)."""
    half = np.array([0.5, 1.0, 0.2])
    for angle, oriented in ((1.3e-7, False), (1e-4, True)):
        rotation = about_axis([1.0, 0.0, 0.0], np.pi / 2 + angle)
        corners = _box_corners(np.array([0.3, -1.0, 2.0]), rotation, half)
        box = Boxes.from_box_corners(corners[None])
        assert box.oriented == oriented
        if not oriented:
            np.testing.assert_array_equal(box.mins, corners.min(axis=0)[None])
            np.testing.assert_array_equal(box.maxs, corners.max(axis=0)[None])
            exact = np.abs(about_axis([1.0, 0.0, 0.0], np.pi / 2)) @ half
            assert np.all(np.abs((box.maxs - box.mins)[0] / 2 - exact) <= 1e-6 * half.sum())


def test_per_frame_oriented_boxes_select_their_axes():
    frames = np.stack([_box_corners(np.zeros(3), about_axis([0.0, 0.0, 1.0], a), np.ones(3)) for a in (0.3, 0.6)])
    boxes = Boxes.from_box_corners(frames[:, None])
    assert boxes.batched and boxes.oriented
    picked = boxes.select(np.array([1]))
    np.testing.assert_array_equal(picked.axes, boxes.axes[1:])
    point = np.array([[[1.2, 0.0, 0.0]], [[1.2, 0.0, 0.0]]])
    expected = [np.abs(about_axis([0, 0, 1], a).T @ point[0, 0]).max() <= 1.0 for a in (0.3, 0.6)]
    np.testing.assert_array_equal(points_inside(point, boxes)[:, 0, 0], expected)


def test_axes_must_be_orthonormal():
    with pytest.raises(SolverInputError, match="orthonormal"):
        Boxes(np.zeros((1, 3)), np.ones((1, 3)), np.full((1, 3, 3), 0.5))


def test_a_chain_keeps_out_of_a_45_degree_box_but_uses_the_corners_its_aligned_box_would_add():
    rotation = about_axis([0.0, 0.0, 1.0], np.pi / 4)
    corners = _box_corners(np.zeros(3), rotation, np.array([1.0, 1.0, 1.0]))
    oriented = Boxes.from_box_corners(corners[None])
    aligned = Boxes.from_corners(corners[None])
    base, target = np.array([2.0, 0.2, 0.0]), np.array([0.2, 2.0, 0.0])
    # The straight line between them passes (1.1, 1.1): inside the aligned box, outside the oriented one.
    # A chain of 4 segments a little longer than that line, started along it.
    direction = (target - base) / np.linalg.norm(target - base)
    start = base + np.linspace(0.0, 1.05 * np.linalg.norm(target - base), 5)[:, None] * direction
    res = solve_chain(start, target, obstacles=oriented)
    assert res.residual < 1e-4
    joints_in, segments_in = penetrations(res.positions, np.c_[np.arange(4), np.arange(1, 5)], oriented)
    assert (int(joints_in), int(segments_in)) == (0, 0)
    # It passes through the space the axis-aligned box would add.
    _, crossing_aligned = penetrations(res.positions, np.c_[np.arange(4), np.arange(1, 5)], aligned)
    assert int(crossing_aligned) > 0
    around = solve_chain(start, target, obstacles=aligned)
    assert penetrations(around.positions, np.c_[np.arange(4), np.arange(1, 5)], aligned)[1] == 0
