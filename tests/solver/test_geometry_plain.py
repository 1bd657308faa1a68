"""The plain-float matrix helpers (solver/geometry_plain.py) against the numpy calls they stand in for, bit for
bit, the sign of zero included: matrix times vector and times points (einsum along contiguous rows), matrix
products (einsum down strided columns) and the minimal rotation between two directions. Inputs span many orders
of magnitude and include signed zeros, where the order of the three additions shows."""

import numpy as np
import pytest

from fullbody_adjust.solver import geometry as g
from fullbody_adjust.solver import geometry_plain as gp


def _values(rng, shape):
    """Random values over many magnitudes, a fifth of them +0.0 or -0.0."""
    v = rng.normal(size=shape) * np.exp(rng.normal(scale=4.0, size=shape))
    zero = rng.random(shape) < 0.2
    return np.where(zero, np.where(rng.random(shape) < 0.5, 0.0, -0.0), v)


def _bits(a):
    return np.asarray(a, dtype=np.float64).view(np.int64)


@pytest.mark.parametrize("seed", range(3))
def test_matrix_times_vector_has_the_bits_of_einsum(seed):
    rng = np.random.default_rng(seed)
    m, v = _values(rng, (3000, 3, 3)), _values(rng, (3000, 3))
    batch = g.apply_matrix(m, v)
    plain = [gp.apply_matrix(mi.tolist(), vi.tolist()) for mi, vi in zip(m, v)]
    assert np.array_equal(_bits(plain), _bits(batch))


@pytest.mark.parametrize("seed", range(3))
def test_matrix_times_points_has_the_bits_of_einsum(seed):
    rng = np.random.default_rng(10 + seed)
    m, points = _values(rng, (1500, 3, 3)), _values(rng, (1500, 4, 3))
    batch = np.einsum("bij,bkj->bki", m, points)  # as two_bone_start turns a chain about its base
    plain = [gp.apply_to_points(mi.tolist(), pi.tolist()) for mi, pi in zip(m, points)]
    assert np.array_equal(_bits(plain), _bits(batch))


@pytest.mark.parametrize("seed", range(3))
def test_matrix_product_has_the_bits_of_einsum(seed):
    rng = np.random.default_rng(20 + seed)
    a, b = _values(rng, (3000, 3, 3)), _values(rng, (3000, 3, 3))
    batch = np.einsum("bij,bjk->bik", a, b)  # as limb_rotations chains the segment rotations
    plain = [gp.matmul(ai.tolist(), bi.tolist()) for ai, bi in zip(a, b)]
    assert np.array_equal(_bits(plain), _bits(batch))


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
