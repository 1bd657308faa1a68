"""Small vectorised vector helpers: every function works on arrays of 3-vectors with any leading shape."""

import math

import numpy as np

from ..errors import SolverInputError

# Norms at or below this count as zero-length. Absolute: callers pass directions of scene-unit vectors and
# only need to tell "no direction at all" from "a direction".
TINY = 1e-300
_EYE = np.eye(3)
# Up to this many rotations swing_rotation builds them from outer products (fewer numpy calls); beyond, entry
# by entry (less memory traffic on large batches).
_FEW_ROTATIONS = 256


def any_set(flags):
    """flags.any() (a truth per element: non-zero, NaN included). One frame's solve asks this about 150 times of
    a few flags each, where np.count_nonzero answers in a fifth of the time (0.28 against 1.43 us measured)."""
    return np.count_nonzero(flags) != 0


def all_set(flags):
    """flags.all(), as any_set counts."""
    return np.count_nonzero(flags) == np.size(flags)


def dot(a, b):
    """Row-wise dot product (...,3)·(...,3) -> (...). Summed in order, (x0 + x1) + x2, so batched and single
    calls round the same, signed zeros included (numpy's add.reduce starts from +0.0, and einsum does not always
    add in order). Other lengths (a horizontal (...,2) offset) are summed by add.reduce."""
    p = np.multiply(a, b)
    if p.shape[-1] != 3:
        return np.add.reduce(p, axis=-1)
    return (p[..., 0] + p[..., 1]) + p[..., 2]


def norm(v):
    """Row-wise Euclidean length (...,3) (or (...,2)) -> (...)."""
    return np.sqrt(dot(v, v))


def cross(a, b):
    """Row-wise cross product; np.cross is several times slower for small arrays."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    out = np.empty(a.shape if a.shape == b.shape else np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def normalize(v, fallback=None):
    """Unit vectors of v (...,3). Zero vectors become `fallback` (broadcast to v's shape, normalised itself);
    without a fallback a zero vector raises SolverInputError."""
    v = np.asarray(v, dtype=np.float64)
    n = norm(v)
    zero = ~(n > TINY)
    if not any_set(zero):
        return v / n[..., None]
    if fallback is None:
        raise SolverInputError("cannot normalise a zero-length vector")
    fb = np.broadcast_to(np.asarray(fallback, dtype=np.float64), v.shape)
    safe = np.where(zero[..., None], fb, v)
    n = norm(safe)
    if not all_set(n > TINY):
        raise SolverInputError("cannot normalise a zero-length vector (fallback is zero too)")
    return safe / n[..., None]


def any_perpendicular(v):
    """A unit vector perpendicular to each (non-zero) v (...,3): crossed with the coordinate axis least
    aligned with v, so the result is well conditioned and deterministic."""
    v = np.asarray(v, dtype=np.float64)
    e = _EYE[np.argmin(np.abs(v), axis=-1)]
    p = cross(v, e)
    return p / norm(p)[..., None]


def unit_or_perpendicular(w, wn, ok, v):
    """Rows (b,3): w / wn where ok (b,), else any_perpendicular(v) (the fallback only built when needed)."""
    if all_set(ok):
        return w / wn[:, None]
    return np.where(ok[:, None], w / np.where(ok, wn, 1.0)[:, None], any_perpendicular(v))


def swing_rotation(old_dirs, new_dirs):
    """Minimal rotation matrices (...,3,3) taking the directions old_dirs to new_dirs (need not be unit).

    Built in the orthonormal frame e1 = old, e2 = the part of new perpendicular to old (Gram-Schmidt twice so
    e2 stays perpendicular to e1 to rounding even when old and new are nearly antiparallel):
        R = I + (cos t - 1)(e1 e1' + e2 e2') + sin t (e2 e1' - e1 e2'),
    a rotation by t = angle(old, new) in the e1-e2 plane. cos and sin come from one atan2 angle so R is
    orthonormal to ~1e-15. Parallel input gives I; exactly antiparallel input a half turn about a
    deterministic axis perpendicular to old."""
    a = normalize(old_dirs)
    b = normalize(new_dirs)
    if a.shape != b.shape:
        a, b = np.broadcast_arrays(a, b)
    c = dot(a, b)
    w = b - c[..., None] * a
    s = norm(w)
    degenerate = ~(s > 1e-14)
    if any_set(degenerate):
        w = np.where(degenerate[..., None], any_perpendicular(a), w)
    w = w - dot(w, a)[..., None] * a
    e2 = w / norm(w)[..., None]
    t = np.arctan2(np.where(degenerate, 0.0, s), c)
    cos_less_1, sin_t = np.cos(t) - 1.0, np.sin(t)
    # Entry by entry from component arrays (far less memory traffic than four outer products), rounding
    # exactly as I + (cos t - 1)(e1 e1' + e2 e2') + sin t (e2 e1' - e1 e2') evaluated left to right.
    if a[..., 0].size <= _FEW_ROTATIONS:
        # Few rotations: whole outer products, fewer numpy calls; the same operations in the same order.
        e1, f2 = a[..., :, None], e2[..., :, None]
        e1t, f2t = a[..., None, :], e2[..., None, :]
        turn = cos_less_1[..., None, None] * (e1 * e1t + f2 * f2t) + _EYE
        return turn + sin_t[..., None, None] * (f2 * e1t - e1 * f2t)
    e1 = [np.ascontiguousarray(a[..., i]) for i in range(3)]
    f2 = [np.ascontiguousarray(e2[..., i]) for i in range(3)]
    out = np.empty(a.shape + (3,))
    for i in range(3):
        for j in range(3):
            turn = cos_less_1 * (e1[i] * e1[j] + f2[i] * f2[j])
            turn += 1.0 if i == j else 0.0  # the identity's entry (+0.0 too: it decides the sign of a zero)
            out[..., i, j] = turn + sin_t * (f2[i] * e1[j] - e1[i] * f2[j])
    return out


def stack_rows(parts):
    """The arrays `parts` concatenated along their first axis (a single part as it is, not copied)."""
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def rotate_about_axis(v, axis, angle):
    """Rotate vectors v (...,3) about `axis` (...,3, need not be unit) by `angle` (...) radians,
    right-handed (Rodrigues)."""
    v = np.asarray(v, dtype=np.float64)
    k = normalize(axis)
    angle = np.asarray(angle, dtype=np.float64)
    cos_a = np.cos(angle)[..., None]
    sin_a = np.sin(angle)[..., None]
    return v * cos_a + cross(k, v) * sin_a + k * (dot(k, v)[..., None] * (1.0 - cos_a))


def apply_matrix(m, v):
    """Row-wise matrix @ vector: (...,3,3) @ (...,3) -> (...,3), each entry summed in order as dot sums (so one
    frame's vectors.apply_matrix on Python floats rounds the same)."""
    return dot(m, np.asarray(v)[..., None, :])


def outward_angles(samples):
    """``samples`` angles around a circle, from 0 outward: 0, +d, -d, +2d, -2d, ..., pi (d = 2 pi / samples), so
    the first that works is the nearest to where one started."""
    angles = [0.0]
    for k in range(1, samples // 2):
        angles += [k * 2 * math.pi / samples, -k * 2 * math.pi / samples]
    return np.array(angles + [math.pi])


def cross_components(u, v):
    """Cross product of two vectors given as lists of three component arrays."""
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def affine_inverse(m):
    """Inverses of affine matrices (…,4,4) (last row 0 0 0 1), in closed form: numpy's batched inv is
    several times slower for many small matrices. One calculation (_inverse_components) on the entries as
    contiguous component arrays, or as plain floats for one matrix (numpy's per-call cost was most of it; a
    singular one goes the arrays' way, to inf or NaN): adjugate rows = cross products of the columns, over the
    determinant."""
    m = np.asarray(m, dtype=np.float64)
    if m.size == 16:
        rows = m.reshape(4, 4).tolist()
        try:
            inv, shift = _inverse_components([row[:3] for row in rows[:3]], [row[3] for row in rows[:3]])
        except ZeroDivisionError:
            pass
        else:
            return np.array([[*inv[i], shift[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]).reshape(m.shape)
    inv, shift = _inverse_components([[np.ascontiguousarray(m[..., i, j]) for j in range(3)] for i in range(3)],
                                     [np.ascontiguousarray(m[..., i, 3]) for i in range(3)])
    out = np.zeros(m.shape)
    for i in range(3):
        for j in range(3):
            out[..., i, j] = inv[i][j]
        out[..., i, 3] = shift[i]
    out[..., 3, 3] = 1.0
    return out


def _inverse_components(a, t):
    """(inverse linear part, its translation) of an affine matrix given as components: ``a`` [i][j] its linear
    part, ``t`` [i] its translation, each a float or an array."""
    col = [[a[0][j], a[1][j], a[2][j]] for j in range(3)]
    rows = [cross_components(col[1], col[2]), cross_components(col[2], col[0]), cross_components(col[0], col[1])]
    det = col[0][0] * rows[0][0] + col[0][1] * rows[0][1] + col[0][2] * rows[0][2]
    inv = [[rows[i][j] / det for j in range(3)] for i in range(3)]
    return inv, [-(inv[i][0] * t[0] + inv[i][1] * t[1] + inv[i][2] * t[2]) for i in range(3)]
