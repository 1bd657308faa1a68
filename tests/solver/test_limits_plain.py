"""Joint limits on one direction in plain floats (solver/limits/limits_plain.py) against the numpy path (solver/limits/joint_limits.py)
on many at once: the same directions and binding flags for hinges with and without twist (directions along the
axis or against the parent, degenerate fallbacks, bends beyond either bound) and cones; and the chain solver's
limit check of a few chains (plain) against its numpy check."""

import numpy as np
import pytest

from fullbody_adjust.solver.chain import model as chain_model
from fullbody_adjust.solver.limits import limits_plain
from fullbody_adjust.solver.chain.model import ChainModel
from fullbody_adjust.solver.chain.settings import ChainSettings
from fullbody_adjust.solver.limits.joint_limits import CONE, FREE, HINGE, JointLimits, apply_cone, apply_hinge, carry_axis


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _directions(rng, n, lo=-np.pi, hi=np.pi, twist=0.0):
    """Unit parents, directions, axes and fallbacks: half the directions on the hinge (bend in [lo, hi], plane
    within the twist), some degenerate: a direction along the axis or against the parent, a fallback along the
    axis too."""
    parent, v, axis, fallback = (_unit(rng, n) for _ in range(4))
    a = axis - np.sum(axis * parent, axis=1, keepdims=True) * parent
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    side = np.cross(a, parent)
    tau = rng.uniform(-twist, twist, (n, 1))
    theta = rng.uniform(lo, hi, (n, 1))
    on_hinge = np.cos(theta) * parent + np.sin(theta) * (np.cos(tau) * side + np.sin(tau) * a)
    v[1::2] = on_hinge[1::2]
    # No bend angle: along the hinge axis, or (with a twist) where the nearest turned plane still holds the axis.
    edge = np.pi / 2 + twist
    v[0::6] = (np.cos(edge) * side + np.sin(edge) * a)[0::6] if twist else a[0::6]
    fallback[0::12] = v[0::12]  # ... with a degenerate fallback too
    v[4::10] = -parent[4::10]
    axis[8::10] = parent[8::10]  # an axis along the parent: any perpendicular
    return parent, v, axis, fallback


@pytest.mark.parametrize("twist", [0.0, 0.4])
@pytest.mark.parametrize("lo, hi", [(0.0, 2.6), (-0.5, 0.5), (-2.9, -0.2)])
def test_hinge_directions_and_binding_as_the_numpy_path(twist, lo, hi):
    rng = np.random.default_rng(int(10 * (lo + hi + twist)) % 2 ** 32)
    parent, v, axis, fallback = _directions(rng, 400, lo, hi, twist)
    limited, binding = apply_hinge(parent, v, axis, lo, hi, fallback, twist)
    assert binding.any() and not binding.all()
    for k in range(len(v)):
        one, binds = limits_plain.apply_hinge(tuple(parent[k]), tuple(v[k]), tuple(axis[k]), lo, hi,
                                              tuple(fallback[k]), twist)
        np.testing.assert_array_equal(one, limited[k], err_msg=f"direction {k}")
        assert binds == binding[k]


def test_cone_directions_and_binding_as_the_numpy_path():
    """Also a direction against the parent, whose fallback (or, that too along the parent, any perpendicular)
    sets the plane it is turned back in."""
    rng = np.random.default_rng(5)
    parent, v, _, fallback = _directions(rng, 400)
    fallback[4::20] = parent[4::20]
    limited, over = apply_cone(parent, v, 1.1, fallback)
    assert over.any() and not over.all()
    for k in range(len(v)):
        one, binds = limits_plain.apply_cone(tuple(parent[k]), tuple(v[k]), 1.1, tuple(fallback[k]))
        np.testing.assert_array_equal(one, limited[k], err_msg=f"direction {k}")
        assert binds == over[k]


@pytest.mark.parametrize("reverse", [False, True])
def test_the_chain_solvers_limit_steps_on_a_few_rows_as_on_many(monkeypatch, reverse):
    """ChainModel._limit and _limit_reverse (the passes' steps: hinge axes carried from the start pose) on 1-4
    rows in plain floats give the numpy path's directions and flags."""
    rng = np.random.default_rng(11 + reverse)
    kind = np.array([CONE, HINGE, HINGE, CONE])
    m, b = len(kind), 4
    limits = JointLimits(kind=kind, cone_angle=np.full(m, 0.8), hinge_min=np.full(m, -0.2), hinge_max=np.full(m, 2.0),
                         hinge_twist=np.array([0.0, 0.0, 0.35, 0.0]), hinge_axis=_unit(rng, m))
    for _ in range(40):
        start = np.concatenate([np.zeros((b, 1, 3)), np.cumsum(_unit(rng, b * m).reshape(b, m, 3), axis=1)], axis=1)
        model = ChainModel(start, start[:, -1], ChainSettings(), limits, None, _unit(rng, b))
        parent, dirs, fallback = _unit(rng, b), _unit(rng, b), _unit(rng, b)
        rows = np.arange(b)
        for i in range(1, m):
            step = (lambda *a: (model._limit_reverse(*a), None)) if reverse else model._limit
            with monkeypatch.context() as numpy_path:
                numpy_path.setattr(chain_model, "_FEW_CHAINS", 0)
                expected, expected_binding = step(i, rows, parent, dirs, fallback)
            for few in (rows[:1], rows[1:3], rows):
                got, binding = step(i, few, parent[few], dirs[few], fallback[few])
                np.testing.assert_array_equal(got, expected[few])
                if not reverse:
                    np.testing.assert_array_equal(binding, expected_binding[few])


@pytest.mark.parametrize("kind", [(CONE, CONE, HINGE), (CONE, HINGE, HINGE), (HINGE, FREE, CONE)])
def test_the_chain_limit_check_of_a_few_chains_as_its_numpy_check(monkeypatch, kind):
    """Poses built joint by joint from directions the numpy limits return (within them), half of them then
    bent off by a little: the plain check flags the same chains as the numpy one, some and not all."""
    rng = np.random.default_rng(sum(kind))
    m, b = len(kind), 4
    limits = JointLimits(kind=np.array(kind), cone_angle=np.full(m, 0.9), hinge_min=np.full(m, -0.3),
                         hinge_max=np.full(m, 2.2), hinge_twist=np.array([0.0, 0.3, 0.0]), hinge_axis=_unit(rng, m))
    broken = kept = 0
    for trial in range(60):
        parent_dir = _unit(rng, b)
        start = np.concatenate([np.zeros((b, 1, 3)), np.cumsum(_unit(rng, b * m).reshape(b, m, 3), axis=1)], axis=1)
        model = ChainModel(start, start[:, -1], ChainSettings(), limits, None, parent_dir)
        dirs, parent = [], parent_dir
        for i in range(m):
            d = _unit(rng, b)
            if kind[i] == CONE:
                d = apply_cone(parent, d, 0.9, d)[0]
            elif kind[i] == HINGE:  # about the axis carried from the start pose, as the check carries it
                axis = np.broadcast_to(limits.hinge_axis[i], (b, 3))
                axis = axis if i == 0 else carry_axis(axis, model.hinge_refs[:, i], parent)
                d = apply_hinge(parent, d, axis, -0.3, 2.2, d, limits.hinge_twist[i])[0]
            dirs.append(d)
            parent = d
        steps = np.stack(dirs, axis=1) * rng.uniform(0.2, 0.5, (b, m, 1))
        pose = np.concatenate([np.zeros((b, 1, 3)), np.cumsum(steps, axis=1)], axis=1)
        model.lengths = np.linalg.norm(steps, axis=-1)  # the pose's own segment lengths
        if trial % 2:
            pose = pose + 0.02 * rng.normal(size=pose.shape)
        rows = np.arange(b)
        with monkeypatch.context() as numpy_path:
            numpy_path.setattr(chain_model, "_FEW_CHAINS", 0)
            expected = model.violations(pose, rows)
        np.testing.assert_array_equal(model.violations(pose, rows), expected)
        broken, kept = broken + expected.sum(), kept + (~expected).sum()
    assert broken and kept


def test_carrying_a_few_hinge_axes_gives_the_bits_of_carrying_many():
    """limits.carry_axis on up to four rows (plain floats) against the same rows among many (numpy), also for
    parents that did not turn, turned right round, or nearly so."""
    from fullbody_adjust.solver.limits import joint_limits as limits
    rng = np.random.default_rng(21)
    n = 400
    axis, ref, parent = _unit(rng, n), _unit(rng, n), _unit(rng, n)
    parent[::9] = ref[::9]  # no swing
    parent[3::9] = -ref[3::9]  # a half turn about a chosen axis
    parent[5::9] = ref[5::9] + 1e-9 * rng.normal(size=parent[5::9].shape)
    assert n > limits._FEW_CARRIED
    many = carry_axis(axis, ref, parent)
    for size in range(1, limits._FEW_CARRIED + 1):
        for start in range(0, n - size, size):
            rows = slice(start, start + size)
            np.testing.assert_array_equal(carry_axis(axis[rows], ref[rows], parent[rows]).view(np.int64),
                                          many[rows].view(np.int64))
