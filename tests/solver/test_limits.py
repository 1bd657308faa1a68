import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fullbody_adjust.solver import CONE, FREE, HINGE, JointLimits, SolverInputError, carry_axis, hinge_axis_from_bend
from fullbody_adjust.solver.limits import apply_cone, apply_hinge

from .strategies import unit_vectors


def _angle(a, b):
    return math.atan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b))


def test_constructors_fill_one_joint_each():
    lim = JointLimits.free(4).with_cone(0, 0.5).with_hinge(2, [0.0, 2.0, 0.0], 0.0, 2.6)
    assert list(lim.kind) == [CONE, FREE, HINGE]
    assert lim.cone_angle[0] == 0.5 and (lim.hinge_min[2], lim.hinge_max[2]) == (0.0, 2.6)
    assert lim.any_active and not JointLimits.free(3).any_active
    assert len(lim) == 3
    per_problem = JointLimits.free(3).with_hinge(1, np.tile([1.0, 0.0, 0.0], (4, 1)), -1.0, 1.0)
    assert per_problem.hinge_axis.shape == (4, 2, 3)


@pytest.mark.parametrize("make, message", [
    (lambda: JointLimits.free(1), "at least 2 joints"),
    (lambda: JointLimits.free(3).with_cone(2, 0.5), "out of range"),
    (lambda: JointLimits.free(3).with_cone(0, 4.0), "cone angle"),
    (lambda: JointLimits.free(3).with_hinge(0, [0.0, 0.0, 1.0], 1.0, 0.5), "hinge range"),
    (lambda: JointLimits.free(3).with_hinge(0, [0.0, 0.0, 0.0], 0.0, 0.5), "zero length"),
    (lambda: JointLimits.free(3).with_cone(0, float("nan")), "NaN"),
])
def test_bad_limits_are_rejected(make, message):
    with pytest.raises(SolverInputError, match=message):
        make()


@settings(deadline=None, max_examples=300)
@given(unit_vectors(), unit_vectors(), unit_vectors(), st.floats(0.0, math.pi))
def test_cone_clamps_to_the_cone_in_the_common_plane(parent, v, fallback, angle):
    out, binding = apply_cone(parent, v, angle, fallback)
    assert np.linalg.norm(out) == pytest.approx(1.0, abs=1e-12)
    assert _angle(parent, out) <= angle + 1e-9
    if _angle(parent, v) <= angle - 1e-7:  # cos resolves small angles to ~1e-8 only
        assert not binding
        np.testing.assert_array_equal(out, v)
    elif binding and np.linalg.norm(np.cross(parent, v)) > 1e-6:
        # rotated toward the parent, staying in the plane of parent and v
        n = np.cross(parent, v)
        assert abs(np.dot(out, n)) <= 1e-9 * np.linalg.norm(n) + 1e-12
        assert _angle(parent, out) == pytest.approx(angle, abs=1e-9)


@settings(deadline=None, max_examples=300)
@given(unit_vectors(), unit_vectors(), unit_vectors(), unit_vectors(),
       st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi))
def test_hinge_puts_the_direction_in_the_plane_with_the_bend_in_range(parent, v, axis, fallback, a, b):
    lo, hi = min(a, b), max(a, b)
    out, _ = apply_hinge(parent, v, axis, lo, hi, fallback)
    assert np.all(np.isfinite(out))
    assert np.linalg.norm(out) == pytest.approx(1.0, abs=1e-12)
    # The axis the hinge uses: the given one made perpendicular to the parent.
    k = axis - np.dot(axis, parent) * parent
    kn = np.linalg.norm(k)
    if kn < 1e-6:
        return
    k /= kn
    assert abs(np.dot(out, k)) <= 1e-12 + 1e-15 / kn  # an axis nearly along the parent is ill-conditioned
    bend = math.atan2(np.dot(np.cross(parent, out), k), np.dot(parent, out))
    assert lo - 1e-9 <= bend <= hi + 1e-9


def test_hinge_direction_along_the_axis_falls_back_to_the_previous_direction():
    parent, axis = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    previous = np.array([0.0, 1.0, 0.0])
    out, _ = apply_hinge(parent, axis.copy(), axis, 0.0, 2.0, previous)
    np.testing.assert_allclose(out, previous, atol=1e-15)


def test_hinge_axis_from_bend_makes_the_start_bend_positive():
    u, v = np.array([1.0, 0.0, 0.0]), np.array([0.6, 0.0, -0.8])
    k = hinge_axis_from_bend(u, v)
    bend = math.atan2(np.dot(np.cross(u, v), k), np.dot(u, v))
    assert bend == pytest.approx(_angle(u, v))
    with pytest.raises(SolverInputError, match="straight"):
        hinge_axis_from_bend(u, 2 * u)


@settings(deadline=None, max_examples=200)
@given(unit_vectors(), unit_vectors(), unit_vectors())
def test_carried_axis_keeps_its_relation_to_the_parent(start_parent, axis, parent):
    moved = carry_axis(axis, start_parent, parent)
    assert np.dot(moved, parent) == pytest.approx(np.dot(axis, start_parent), abs=1e-12)
    assert np.linalg.norm(moved) == pytest.approx(1.0, abs=1e-12)
