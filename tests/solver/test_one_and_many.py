"""Every calculation written once on components (solver/lanes.py): F frames solved together against each frame
solved alone, bit for bit, on random problems (hypothesis) and on captured degenerate ones; and the lanes'
primitives on one float against numpy on many."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver import body, lanes
from fullbody_adjust.solver.errors import SolverInputError

BENT = np.radians(15.0)
MANY = lanes.FEW + 3  # more frames than lanes.run solves one at a time


def _bits(a):
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def _alone_and_together(fn, frames, *args):
    """fn on all frames, and on each frame alone (rows of (F,...) arrays; None passes); both must agree: the
    same bits, or the same error raised by the batch and by some frame alone."""
    cut = lambda k: [None if a is None else a[k:k + 1] for a in args]  # noqa: E731
    try:
        together = fn(*args)
    except SolverInputError as error:
        alone_errors = []
        for k in range(frames):
            try:
                fn(*cut(k))
            except SolverInputError as one:
                alone_errors.append(str(one))
        assert str(error) in alone_errors
        return None
    for k in range(frames):
        np.testing.assert_array_equal(_bits(fn(*cut(k))[0]), _bits(together[k]), err_msg=f"frame {k}")
    return together


def _hinge_frames(rng, n):
    """Captured-style limbs: bent, about the clear-bend and slight-bend thresholds, straight, hyperextended,
    folded back, along the bend side, X axes along the limb."""
    parent = rng.normal(size=(n, 3)) * rng.uniform(0.05, 2.0, (n, 1))
    child, side, x = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    u = parent / np.linalg.norm(parent, axis=1, keepdims=True)
    perp = np.cross(u, side)
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    theta = np.concatenate([rng.uniform(-0.3, 0.3, n // 4), BENT + rng.uniform(-1e-9, 1e-9, n // 8),
                            rng.uniform(-2e-3, 2e-3, n // 8), np.zeros(n // 8), rng.uniform(-3.0, 3.0, n)])[:n]
    child[: n // 2] = (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * perp)[: n // 2]
    child[3::17] = -u[3::17]
    side[5::11] = u[5::11] * 2.0
    side[6::13] = u[6::13] + 0.29 * perp[6::13]
    x[7::9] = u[7::9] * 3.0
    x[8::9] = u[8::9] + 1e-7 * perp[8::9]
    return parent, child, side, x


def _hinge(parent, child, side, x):
    return body._hinge_axis(parent, child, side, x, BENT)


@pytest.mark.parametrize("with_x", [True, False])
def test_hinge_axes_captured(with_x):
    parent, child, side, x = _hinge_frames(np.random.default_rng(11 + with_x), 600)
    axes = _alone_and_together(_hinge, 600, parent, child, side, x if with_x else None)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1.0, atol=1e-15)


vectors3 = st.integers(1, 2 * MANY).flatmap(
    lambda f: st.tuples(*[arrays(np.float64, (f, 3), elements=st.floats(-1e3, 1e3) | st.sampled_from([0.0, 1e-12]))
                          for _ in range(4)], st.booleans()))


@settings(max_examples=200, deadline=None)
@given(vectors3)
def test_hinge_axes_random(problem):
    parent, child, side, x, with_x = problem
    _alone_and_together(_hinge, len(parent), parent, child, side, x if with_x else None)


@pytest.mark.parametrize("bad", ["zero parent", "zero child", "nan"])
def test_hinge_axes_degenerate(bad):
    parent, child, side, x = (a[:MANY] for a in _hinge_frames(np.random.default_rng(5), 40))
    {"zero parent": parent, "zero child": child, "nan": x}[bad][1] = 0.0 if bad != "nan" else np.nan
    _alone_and_together(_hinge, MANY, parent, child, side, x)


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_primitives_on_one_value_as_numpy_on_many(a, b):
    arr_a, arr_b = np.array([a, a]), np.array([b, b])
    with np.errstate(invalid="ignore"):
        pairs = [(lanes.divide(a, b), lanes.divide(arr_a, arr_b)), (lanes.sqrt(a), lanes.sqrt(arr_a)),
                 (lanes.arctan2(a, b), lanes.arctan2(arr_a, arr_b)), (lanes.cos(a), lanes.cos(arr_a)),
                 (lanes.sin(a), lanes.sin(arr_a))]
    for one, many in pairs:
        assert isinstance(one, float)
        np.testing.assert_array_equal(_bits(one), _bits(many[0]))
