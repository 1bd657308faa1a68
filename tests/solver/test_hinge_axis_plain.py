"""The default hinge axis on one frame in plain floats (solver/hinge_axis_plain.py) against the numpy path
(body._hinge_axis on many frames at once): the same bits on bent, slightly bent, straight and hyperextended limbs,
limbs along the bend side, bone X axes along the limb or absent; and the same error where numpy raises one."""

import numpy as np
import pytest

from fullbody_adjust.solver import body, hinge_axis_plain
from fullbody_adjust.solver.errors import SolverInputError

BENT = np.radians(15.0)


def _frames(rng, n):
    """Parent and child segments, bend sides and X axes, a share of them degenerate."""
    parent = rng.normal(size=(n, 3)) * rng.uniform(0.05, 2.0, (n, 1))
    child = rng.normal(size=(n, 3))
    side = rng.normal(size=(n, 3))
    x = rng.normal(size=(n, 3))
    u = parent / np.linalg.norm(parent, axis=1, keepdims=True)
    perp = np.cross(u, side)
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    # Bend angles about the threshold of a clear bend, about 1e-3 (slight), exactly straight, and hyperextended.
    theta = np.concatenate([rng.uniform(-0.3, 0.3, n // 4), BENT + rng.uniform(-1e-9, 1e-9, n // 8),
                            rng.uniform(-2e-3, 2e-3, n // 8), np.zeros(n // 8), rng.uniform(-3.0, 3.0, n)])[:n]
    child[: n // 2] = (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * perp)[: n // 2]
    child[3::17] = -u[3::17]  # folded back on the parent: no bend plane
    side[5::11] = u[5::11] * 2.0  # the limb along the bend side: any perpendicular
    side[6::13] = u[6::13] + 0.29 * perp[6::13]  # about the weak threshold
    x[7::9] = u[7::9] * 3.0  # an X axis along the limb: not used
    x[8::9] = u[8::9] + 1e-7 * perp[8::9]  # ... or nearly
    return parent, child, side, x


@pytest.mark.parametrize("with_x", [True, False])
def test_axes_as_the_numpy_path(with_x):
    rng = np.random.default_rng(11 + with_x)
    parent, child, side, x = _frames(rng, 600)
    x = x if with_x else None
    batch = body._hinge_axis(parent, child, side, x, BENT)  # > _FEW_FRAMES: numpy
    for k in range(len(parent)):
        one = hinge_axis_plain.hinge_axes(parent[k:k + 1], child[k:k + 1], side[k:k + 1],
                                          None if x is None else x[k:k + 1], BENT)
        assert one is not None, f"frame {k}"
        np.testing.assert_array_equal(one[0], batch[k], err_msg=f"frame {k}")


def test_a_few_frames_take_the_plain_path_with_the_same_axes():
    rng = np.random.default_rng(3)
    parent, child, side, x = _frames(rng, 40)
    for k in range(0, 40, 4):
        cut = slice(k, k + 4)
        np.testing.assert_array_equal(body._hinge_axis(parent[cut], child[cut], side[cut], x[cut], BENT),
                                      body._hinge_axis(parent, child, side, x, BENT)[cut])


@pytest.mark.parametrize("bad", ["zero parent", "zero child", "nan"])
def test_what_numpy_cannot_normalise_it_leaves_to_numpy(bad):
    rng = np.random.default_rng(5)
    parent, child, side, x = (a[:2] for a in _frames(rng, 40))
    if bad == "zero parent":
        parent[1] = 0.0
    elif bad == "zero child":
        child[1] = 0.0
    else:
        x[1, 0] = np.nan
    assert hinge_axis_plain.hinge_axes(parent, child, side, x, BENT) is None
    try:
        expected = body._hinge_axis(np.repeat(parent, 3, axis=0), np.repeat(child, 3, axis=0),
                                    np.repeat(side, 3, axis=0), np.repeat(x, 3, axis=0), BENT)[::3]
    except SolverInputError as numpy_error:
        with pytest.raises(SolverInputError, match=str(numpy_error)):
            body._hinge_axis(parent, child, side, x, BENT)
    else:
        np.testing.assert_array_equal(body._hinge_axis(parent, child, side, x, BENT), expected)
