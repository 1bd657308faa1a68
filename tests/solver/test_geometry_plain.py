"""The plain-float matrix helpers (solver/maths/geometry_plain.py) against the numpy calls they stand in for, bit for
bit, the sign of zero included: matrix times vector and times points (einsum along contiguous rows), matrix
products (einsum down strided columns) and the minimal rotation between two directions. Inputs span many orders
of magnitude and include signed zeros, where the order of the three additions shows."""

import numpy as np
import pytest

from fullbody_adjust.solver.maths import geometry as g
from fullbody_adjust.solver.maths import geometry_plain as gp


def _values(rng, shape):
    """Random values over many magnitudes, a fifth of them +0.0 or -0.0."""
    v = rng.normal(size=shape) * np.exp(rng.normal(scale=4.0, size=shape))
    zero = rng.random(shape) < 0.2
    return np.where(zero, np.where(rng.random(shape) < 0.5, 0.0, -0.0), v)


def _bits(a):
    return np.asarray(a, dtype=np.float64).view(np.int64)


# The plain products and the numpy calls they stand in for, with the second operand's shape per row.
PRODUCTS = {
    "matrix times vector": (gp.apply_matrix, g.apply_matrix, (3,)),
    "matrix times points": (gp.apply_to_points, lambda m, p: np.einsum("bij,bkj->bki", m, p), (4, 3)),  # two_bone_start
    "matrix product": (gp.matmul, lambda a, b: np.einsum("bij,bjk->bik", a, b), (3, 3)),  # limb_rotations
}


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("product", PRODUCTS)
def test_matrix_products_have_the_bits_of_einsum(product, seed):
    plain, numpy_call, shape = PRODUCTS[product]
    rng = np.random.default_rng(seed)
    a, b = _values(rng, (2000, 3, 3)), _values(rng, (2000,) + shape)
    got = [plain(x.tolist(), y.tolist()) for x, y in zip(a, b)]
    assert np.array_equal(_bits(got), _bits(numpy_call(a, b)))


def test_all_zero_products_give_positive_zero_as_einsum_does():
    m = [[-1.0, 1.0, -1.0]] * 3
    v = [0.0, -0.0, 0.0]
    assert np.signbit(np.einsum("...ij,...j->...i", np.array(m), np.array(v))).tolist() == [False] * 3
    assert [np.signbit(x) for x in gp.apply_matrix(m, v)] == [False] * 3
    assert [np.signbit(x) for row in gp.matmul(m, [v, v, v]) for x in row] == [False] * 9


@pytest.mark.parametrize("seed", range(2))
def test_swing_rotation_has_the_bits_of_the_numpy_path(seed):
    rng = np.random.default_rng(30 + seed)
    old = rng.normal(size=(2000, 3))
    new = rng.normal(size=(2000, 3))
    new[::7] = old[::7] * rng.uniform(0.5, 2.0, size=(len(old[::7]), 1))  # parallel: no swing
    new[3::7] = -old[3::7]  # antiparallel: a half turn about a chosen axis
    new[5::7] = old[5::7] + 1e-9 * rng.normal(size=(len(old[5::7]), 3))  # nearly parallel
    for o, n in zip(old, new):  # one at a time: the numpy path's few-rotations form, as the twins use it
        assert np.array_equal(_bits(gp.swing_rotation(o.tolist(), n.tolist())),
                              _bits(g.swing_rotation(o[None], n[None])[0]))
