"""The chain solves that need no iteration, in plain floats (solver/chain/settled.py), against the numpy path of
ChainModel.solve: a target beyond reach (one stretched pass, limits applied) and a start already at its target
(untouched when within its limits). Every field of the result is equal bit for bit, on 1-4 chains at once, with
cones, hinges (with and without twist) and free joints; problems the plain path cannot settle (a target within
reach and not met, a start that breaks a limit) are left to the numpy path and come out the same too."""

import numpy as np
import pytest

from fullbody_adjust.solver.chain.model import ChainModel
from fullbody_adjust.solver.chain.settings import ChainSettings
from fullbody_adjust.solver.limits.joint_limits import CONE, FREE, HINGE, JointLimits, apply_cone, apply_hinge

SETTINGS = ChainSettings()


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _pose_within_limits(rng, limits, parent_dir):
    """A pose (b,n,3) built joint by joint from directions the numpy limits return (so within them, up to
    rounding). A solve starting from it gives its hinge axes at its own parent directions: not carried."""
    b, m = parent_dir.shape[0], len(limits)
    dirs, parent = [], parent_dir
    for i in range(m):
        d = _unit(rng, b)
        if limits.kind[i] == CONE:
            d = apply_cone(parent, d, limits.cone_angle[i], d)[0]
        elif limits.kind[i] == HINGE:
            axis = np.broadcast_to(limits.hinge_axis[i], (b, 3))
            d = apply_hinge(parent, d, axis, limits.hinge_min[i], limits.hinge_max[i], d, limits.hinge_twist[i])[0]
        dirs.append(d)
        parent = d
    steps = np.stack(dirs, axis=1) * rng.uniform(0.2, 0.5, (b, m, 1))
    return np.concatenate([np.zeros((b, 1, 3)), np.cumsum(steps, axis=1)], axis=1)


def _solve_both(monkeypatch, start, targets, limits, parent_dir):
    """(plain path's result, numpy path's result, whether the plain path settled the call)."""
    model = ChainModel(start, targets, SETTINGS, limits, None, parent_dir)
    settled = model._solve_settled(start) is not None
    got = model.solve(start)
    with monkeypatch.context() as numpy_path:
        numpy_path.setattr(ChainModel, "_solve_settled", lambda self, start: None)
        expected = ChainModel(start, targets, SETTINGS, limits, None, parent_dir).solve(start)
    return got, expected, settled


def _assert_same(got, expected):
    np.testing.assert_array_equal(got.positions.view(np.int64), expected.positions.view(np.int64))
    np.testing.assert_array_equal(got.residual.view(np.int64), expected.residual.view(np.int64))
    for field in ("iterations", "reachable", "status", "reason"):
        a, b = getattr(got, field), getattr(expected, field)
        assert a.dtype == b.dtype and a.tolist() == b.tolist(), field


@pytest.mark.parametrize("kind, twist", [((CONE, CONE, HINGE), (0.0, 0.0, 1.39)),  # an arm: clavicle, shoulder, elbow
                                         ((CONE, HINGE, CONE), (0.0, 0.0, 0.0)),  # a leg: hip, knee, ankle
                                         ((FREE, HINGE, HINGE, CONE), (0.0, 0.3, 0.0, 0.0))])
def test_settled_chains_get_the_bits_of_the_numpy_path(monkeypatch, kind, twist):
    rng = np.random.default_rng(len(kind) + int(10 * sum(twist)))
    m = len(kind)
    limits = JointLimits(kind=np.array(kind), cone_angle=np.full(m, 0.9), hinge_min=np.full(m, -0.3),
                         hinge_max=np.full(m, 2.2), hinge_twist=np.array(twist), hinge_axis=_unit(rng, m))
    settled_rows = {"beyond": 0, "met": 0, "broken limit": 0, "within reach": 0}
    unsettled_calls = dict(settled_rows)
    for trial in range(80):
        b = 1 + trial % 4
        parent_dir = _unit(rng, b)
        start = _pose_within_limits(rng, limits, parent_dir)
        reach = np.linalg.norm(np.diff(start, axis=1), axis=-1).sum(axis=1)
        what = rng.choice(["beyond", "met", "broken limit", "within reach"], size=b, p=[0.4, 0.4, 0.1, 0.1])
        if trial % 3 == 0:
            what[:] = what[0]  # one kind throughout: every row settled, or none
        targets = start[:, -1] + rng.normal(scale=2e-6, size=(b, 3))  # met within the tolerance
        far = what == "beyond"
        targets[far] = start[far, 0] + _unit(rng, far.sum()) * (reach[far] * rng.uniform(1.05, 3.0, far.sum()))[:, None]
        near = what == "within reach"
        targets[near] = start[near, 0] + _unit(rng, near.sum()) * (0.5 * reach[near])[:, None]
        broken = what == "broken limit"
        start[broken, -1] = 2.0 * start[broken, -2] - start[broken, -1]  # the last segment turned right round
        targets[broken] = start[broken, -1]
        got, expected, settled = _solve_both(monkeypatch, start, targets, limits, parent_dir)
        _assert_same(got, expected)
        if settled:
            for w in what:
                settled_rows[w] += 1
        elif len(set(what)) == 1:
            unsettled_calls[what[0]] += 1
    # Both kinds settled in plain floats, the other two never...
    assert settled_rows["beyond"] and settled_rows["met"], settled_rows
    assert not settled_rows["within reach"] and not settled_rows["broken limit"], settled_rows
    # ... and left to the numpy path, whole calls of them among the trials.
    assert unsettled_calls["within reach"] and unsettled_calls["broken limit"], unsettled_calls


def test_a_start_that_breaks_a_limit_is_left_to_the_iterations(monkeypatch):
    rng = np.random.default_rng(7)
    limits = JointLimits.free(4).with_cone(1, 0.2)
    start = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, 2.0]]])  # joint 1 bent 90 degrees
    got, expected, settled = _solve_both(monkeypatch, start, start[:, -1].copy(), limits, _unit(rng, 1))
    assert not settled and got.iterations[0] > 0
    _assert_same(got, expected)


def test_a_target_straight_behind_a_cone_turns_the_segment_to_its_start_side(monkeypatch):
    """Joint 0's cone faces +z and the target lies straight down: the aim has no side of its own, and the
    numpy pass turns it back toward the start segment's side (its fallback). The plain pass does the same."""
    limits = JointLimits.free(3).with_cone(0, 0.5)
    for side in ([1.0, 0.0, 0.0], [0.0, -1.0, 0.0]):
        start = np.array([[[0.0, 0.0, 0.0], side, np.add(side, [0.0, 0.0, 1.0]).tolist()]])
        targets = np.array([[0.0, 0.0, -5.0]])
        got, expected, settled = _solve_both(monkeypatch, start, targets, limits, np.array([[0.0, 0.0, 1.0]]))
        assert settled and got.status[0] == "unreachable"
        assert np.dot(got.positions[0, 1], side) > 0.4  # bent toward the start side, to the cone's edge
        _assert_same(got, expected)
