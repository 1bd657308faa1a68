import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fullbody_adjust.solver import SolverInputError
from fullbody_adjust.solver.maths.geometry import normalize, rotate_about_axis, swing_rotation
from fullbody_adjust.solver.maths import geometry
from fullbody_adjust.solver.maths.geometry import affine_inverse, any_perpendicular, cross

from .strategies import unit_vectors


def test_normalize_gives_unit_vectors_and_uses_the_fallback_for_zero_rows():
    v = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [0.0, -2.0, 0.0]])
    out = normalize(v, fallback=[0.0, 0.0, 5.0])
    np.testing.assert_allclose(out, [[0.6, 0.8, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def test_normalize_without_fallback_rejects_zero_vectors():
    with pytest.raises(SolverInputError, match="zero-length"):
        normalize(np.zeros(3))


@settings(deadline=None, max_examples=300)
@given(unit_vectors(), unit_vectors(), st.floats(0.1, 10.0), st.floats(0.1, 10.0))
def test_swing_rotation_takes_old_to_new_and_is_a_rotation(a, b, sa, sb):
    r = swing_rotation(a * sa, b * sb)
    np.testing.assert_allclose(r @ a, b, atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)
    # Minimal: it leaves the common normal of old and new alone.
    n = np.cross(a, b)
    if np.linalg.norm(n) > 1e-6:
        np.testing.assert_allclose(r @ n, n, atol=1e-12)


@settings(deadline=None, max_examples=200)
@given(unit_vectors(), st.floats(-1e-7, 1e-7), st.floats(-1e-7, 1e-7))
def test_swing_rotation_is_robust_near_antiparallel(a, e1, e2):
    p = any_perpendicular(a)
    q = np.cross(a, p)
    b = -a + e1 * p + e2 * q
    r = swing_rotation(a, b)
    np.testing.assert_allclose(r @ a, b / np.linalg.norm(b), atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)


def test_swing_rotation_parallel_is_identity_and_batches():
    a = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    r = swing_rotation(a, a * 3.0)
    np.testing.assert_allclose(r, np.broadcast_to(np.eye(3), (2, 3, 3)), atol=1e-15)
    r = swing_rotation(a, -a)
    np.testing.assert_allclose(np.einsum("bij,bj->bi", r, a), -a, atol=1e-15)


@settings(deadline=None, max_examples=200)
@given(unit_vectors(), unit_vectors(), st.floats(-math.pi, math.pi))
def test_rotate_about_axis_keeps_length_axis_part_and_turns_by_the_angle(v, k, angle):
    w = rotate_about_axis(v, k * 2.0, angle)
    assert np.linalg.norm(w) == pytest.approx(1.0, abs=1e-12)
    assert np.dot(w, k) == pytest.approx(np.dot(v, k), abs=1e-12)
    # The perpendicular parts differ by exactly `angle`, right-handed about k.
    pv, pw = v - np.dot(v, k) * k, w - np.dot(w, k) * k
    if np.linalg.norm(pv) > 1e-6:
        measured = math.atan2(np.dot(np.cross(pv, pw), k), np.dot(pv, pw))
        assert math.remainder(measured - angle, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


def test_cross_matches_numpy():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    np.testing.assert_allclose(cross(a, b), np.cross(a, b), atol=1e-15)


def test_affine_inverse_inverts_object_transforms():
    rng = np.random.default_rng(3)
    rotations = np.linalg.qr(rng.normal(size=(20, 3, 3)))[0]
    matrices = np.zeros((20, 4, 4))
    matrices[:, :3, :3] = rotations * rng.uniform(0.01, 100.0, (20, 1, 3))  # rotated, non-uniformly scaled
    matrices[:, :3, 3] = rng.normal(size=(20, 3))
    matrices[:, 3, 3] = 1.0
    inverse = affine_inverse(matrices)
    np.testing.assert_allclose(inverse @ matrices, np.broadcast_to(np.eye(4), matrices.shape), atol=1e-12)
    np.testing.assert_allclose(inverse, np.linalg.inv(matrices), rtol=1e-10, atol=1e-12)


def test_one_affine_inverse_equals_its_row_of_a_batch_bit_for_bit():
    """A single matrix takes the plain-float path, a batch the numpy one: the same operations, the same bits; a
    singular matrix gives what the batch gives (inf or NaN), not an error."""
    rng = np.random.default_rng(8)
    matrices = np.zeros((200, 4, 4))
    matrices[:, :3, :] = rng.normal(size=(200, 3, 4)) * rng.uniform(1e-3, 1e3, (200, 1, 1))
    matrices[:, 3, 3] = 1.0
    matrices[7, :3, 2] = 0.0  # singular
    matrices[9, :3, 1] = matrices[9, :3, 0]  # singular
    with np.errstate(divide="ignore", invalid="ignore"):
        batch = affine_inverse(matrices)
        for k in range(len(matrices)):
            np.testing.assert_array_equal(affine_inverse(matrices[k]), batch[k], err_msg=f"matrix {k}")
            np.testing.assert_array_equal(affine_inverse(matrices[k:k + 1]), batch[k:k + 1])
    assert not np.isfinite(batch[[7, 9]]).all()


def test_dot_and_norm_take_horizontal_offsets_too():
    """A horizontal (...,2) offset (a foot's drift off its path) has a length as a 3-vector does; the in-order sum of
    three components, one row or many."""
    rng = np.random.default_rng(7)
    flat = rng.normal(size=(5, 2))
    assert np.allclose(geometry.norm(flat), np.hypot(flat[:, 0], flat[:, 1]), rtol=0, atol=1e-15)
    assert geometry.norm(np.array([3.0, 4.0])) == 5.0
    rows = rng.normal(size=(7, 3))
    assert np.array_equal(geometry.dot(rows, rows), (rows[:, 0] * rows[:, 0] + rows[:, 1] * rows[:, 1])
                          + rows[:, 2] * rows[:, 2])
