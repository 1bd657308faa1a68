import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fullbody_adjust.solver import SolverInputError
from fullbody_adjust.solver.limits.joint_limits import CONE, FREE, HINGE, JointLimits, carry_axis, cone, hinge, hinge_twist

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
    assert list(lim.hinge_twist) == [0.0, 0.0, 0.0] and lim.hinge_reference is None
    assert list(lim.with_hinge(1, [0.0, 0.0, 1.0], 0.0, 1.0, twist=0.7).hinge_twist) == [0.0, 0.7, 0.0]


def _fields(lim):
    return lim.kind, lim.cone_angle, lim.hinge_axis, lim.hinge_min, lim.hinge_max


@pytest.mark.parametrize("make, message", [
    (lambda: JointLimits.free(1), "at least 2 joints"),
    (lambda: JointLimits.free(3).with_cone(2, 0.5), "out of range"),
    (lambda: JointLimits.free(3).with_cone(0, 4.0), "cone angle"),
    (lambda: JointLimits.free(3).with_hinge(0, [0.0, 0.0, 1.0], 1.0, 0.5), "hinge range"),
    (lambda: JointLimits.free(3).with_hinge(0, [0.0, 0.0, 0.0], 0.0, 0.5), "zero length"),
    (lambda: JointLimits.free(3).with_cone(0, float("nan")), "NaN"),
    (lambda: JointLimits.free(3).with_hinge(1, [0.0, 0.0, 1.0], 0.0, 1.0, twist=math.pi / 2), "hinge twist"),
    (lambda: JointLimits.free(3).with_hinge(1, [0.0, 0.0, 1.0], 0.0, 1.0, twist=-0.1), "hinge twist"),
    (lambda: JointLimits(*_fields(JointLimits.free(3)), hinge_twist=[0.1]), "2 entries"),
    (lambda: JointLimits(*_fields(JointLimits.free(3)), hinge_reference=np.zeros((3, 3))), r"hinge_reference must be"),
    (lambda: JointLimits(*_fields(JointLimits.free(3)), hinge_reference=np.full((2, 3), np.nan)), "NaN"),
])
def test_bad_limits_are_rejected(make, message):
    with pytest.raises(SolverInputError, match=message):
        make()


@settings(deadline=None, max_examples=300)
@given(unit_vectors(), unit_vectors(), unit_vectors(), st.floats(0.0, math.pi))
def test_cone_clamps_to_the_cone_in_the_common_plane(parent, v, fallback, angle):
    out, binding = cone(parent, v, angle, fallback)
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
    out, _ = hinge(parent, v, axis, lo, hi, fallback)
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
    out, _ = hinge(parent, axis.copy(), axis, 0.0, 2.0, previous)
    np.testing.assert_allclose(out, previous, atol=1e-15)


@settings(deadline=None, max_examples=200)
@given(unit_vectors(), unit_vectors(), unit_vectors())
def test_carried_axis_keeps_its_relation_to_the_parent(start_parent, axis, parent):
    moved = carry_axis(axis, start_parent, parent)
    assert np.dot(moved, parent) == pytest.approx(np.dot(axis, start_parent), abs=1e-12)
    assert np.linalg.norm(moved) == pytest.approx(1.0, abs=1e-12)


def _hinge_direction(parent, axis, bend, tau):
    """The unit child direction bent by `bend` about `axis` (perpendicular to `parent`) turned by `tau` about the
    parent: the generator of the twisted hinge's allowed set."""
    a = axis - np.dot(axis, parent) * parent
    a /= np.linalg.norm(a)
    side = np.cross(a, parent)
    return math.cos(bend) * parent + math.sin(bend) * (math.cos(tau) * side + math.sin(tau) * a)


@settings(deadline=None, max_examples=150)
@given(unit_vectors(), unit_vectors(), unit_vectors(), st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi),
       st.floats(0.0, 1.5))
@example(parent=np.array([9.42809042e-10, 1.0, 1.0]) / np.linalg.norm([9.42809042e-10, 1.0, 1.0]),
         v=np.array([-1.0, 0.0, 0.0]), axis=np.array([1.0, 0.0, 0.0]), a=0.0, b=3.0,
         twist=0.0)  # v along the axis: every bend is as near (Hypothesis found a 1.3e-9 miss near this)
def test_twisted_hinge_gives_the_nearest_allowed_direction(parent, v, axis, a, b, twist):
    """The result is in the allowed set (bend in [lo, hi] in a plane turned by at most `twist` about the parent)
    and no direction of that set, sampled densely, is nearer to v."""
    lo, hi = min(a, b), max(a, b)
    if np.linalg.norm(np.cross(axis, parent)) < 1e-3:
        return
    out, binding = hinge(parent, v, axis, lo, hi, v, twist)
    assert np.linalg.norm(out) == pytest.approx(1.0, abs=1e-12)
    # In the plane turned by the measured twist clamped to the range (the twist of a direction near the parent
    # is ill-conditioned; its distance from the plane is not).
    tau = float(np.clip(hinge_twist(parent, out, axis), -twist, twist))
    k = axis - np.dot(axis, parent) * parent
    k /= np.linalg.norm(k)
    k_tau = math.cos(tau) * k - math.sin(tau) * np.cross(k, parent)
    assert abs(np.dot(out, k_tau)) <= 1e-9
    bend = math.atan2(np.dot(np.cross(parent, out), k_tau), np.dot(parent, out))
    assert any(lo - 1e-9 <= x <= hi + 1e-9 for x in (bend, bend - 2 * math.pi, bend + 2 * math.pi))
    bends = np.linspace(lo, hi, 61)
    taus = np.linspace(-twist, twist, 61)
    grid = np.array([_hinge_direction(parent, axis, t, u) for t in bends for u in taus])
    nearest = np.min(np.linalg.norm(grid - v, axis=1))
    step = max(hi - lo, 2 * twist) / 60  # grid spacing (radians): the grid point is at most ~step from the best
    # (1e-8: where v lies along the axis every bend is as near, to the rounding of a plane tilted by ~1e-9.)
    assert np.linalg.norm(out - v) <= nearest + 1e-8
    assert nearest <= np.linalg.norm(out - v) + step + 1e-9
    assert binding == (np.linalg.norm(out - v) > 1e-12)


@settings(deadline=None, max_examples=150)
@given(unit_vectors(), unit_vectors(), st.floats(0.05, 3.0), st.floats(-1.5, 1.5), st.booleans())
def test_twist_angle_recovers_the_plane_turn(parent, axis, bend, tau, negative):
    """A child bent in the plane turned by tau: hinge_twist gives tau back, whichever side it bends to;
    a twisted hinge with a range covering it leaves the child where it is."""
    if np.linalg.norm(np.cross(axis, parent)) < 1e-3:
        return
    child = _hinge_direction(parent, axis, -bend if negative else bend, tau)
    assert hinge_twist(parent, child, axis) == pytest.approx(tau, abs=1e-9)
    out, binding = hinge(parent, child, axis, -3.0, 3.0, child, abs(tau) + 0.01)
    np.testing.assert_allclose(out, child, atol=1e-12)
    assert not binding
    assert hinge_twist(parent, parent, axis) == 0.0  # straight: every plane holds it


def test_zero_twist_is_the_plain_hinge():
    parent, axis = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    v = np.array([0.3, 0.5, 0.81])
    v /= np.linalg.norm(v)
    plain = hinge(parent, v, axis, 0.0, 2.0, v)
    for zero in (0.0, np.zeros(1)):
        twisted = hinge(parent, v, axis, 0.0, 2.0, v, zero)
        np.testing.assert_array_equal(twisted[0], plain[0])
