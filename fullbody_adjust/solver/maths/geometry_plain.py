"""maths/geometry.py's helpers on one 3-vector or 3x3 matrix in plain Python floats, for the single-frame twins of the
numpy paths (limits/limits_plain.py, chain/settled.py, chain/iterate_plain.py, chain/finish.py).
Vectors are 3-tuples (or lists), matrices their rows. Each does the numpy helper's operations
in its order (numpy adds a 3-vector's components as (x0 + x1) + x2), so it returns the same bits. The trigonometry
calls numpy's own routines on the one value instead of Python's math module: numpy may use its own SIMD
implementations of arccos, sin, cos and arctan2 on some processors. The matrix products add as einsum does: from
+0.0, the three products along a contiguous row as (x0 + x2) + x1 (x0 and x2 share a vector lane), along a
strided column in order (measured on 100,000s of random matrices, numpy 1.26 and 2.5). Calling einsum on one matrix
cost ten times more. That a call on one value rounds as numpy's call on many does is what the
twins' tests check, on every run (numpy 1.26 and 2.5 on x86-64 with AVX2 here).

Divisions by zero raise ZeroDivisionError where numpy would give inf or NaN: the callers then leave the frame to
the numpy path."""

import math

import numpy as np

from ..errors import SolverInputError
from .geometry import TINY

EYE = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def scaled(v, s):
    return (v[0] * s, v[1] * s, v[2] * s)


def divided(v, s):
    return (v[0] / s, v[1] / s, v[2] / s)


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def norm(v):
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def normalize(v):
    """geometry.normalize without a fallback (SolverInputError on a zero vector)."""
    n = norm(v)
    if not n > TINY:
        raise SolverInputError("cannot normalise a zero-length vector")
    return (v[0] / n, v[1] / n, v[2] / n)


def any_perpendicular(v):
    """Crossed with the axis of the smallest |component| (numpy's argmin: the first NaN, else the first
    smallest)."""
    mags = [abs(x) for x in v]
    nans = [k for k, x in enumerate(mags) if x != x]
    return divided_by_norm(cross(v, EYE[nans[0] if nans else mags.index(min(mags))]))


def divided_by_norm(v):
    return divided(v, norm(v))


def rotate_about_axis(v, axis, angle):
    k = normalize(axis)
    cos_a, sin_a = float(np.cos(angle)), float(np.sin(angle))
    kv, along = cross(k, v), dot(k, v) * (1.0 - cos_a)
    return (v[0] * cos_a + kv[0] * sin_a + k[0] * along, v[1] * cos_a + kv[1] * sin_a + k[1] * along,
            v[2] * cos_a + kv[2] * sin_a + k[2] * along)


def rotation_about(k, angle):
    """limb_rotations._rotation_about for one unit axis k (Rodrigues): the rows of c I + s [k]x + (1 - c) k k'."""
    c, s = float(np.cos(angle)), float(np.sin(angle))
    kx = ((0.0, -k[2], k[1]), (k[2], 0.0, -k[0]), (-k[1], k[0], 0.0))
    return [[c * EYE[i][j] + s * kx[i][j] + (1.0 - c) * (k[i] * k[j]) for j in (0, 1, 2)] for i in (0, 1, 2)]


def swing_rotation(old, new):
    """geometry.swing_rotation (its few-rotations form): the rows of the 3x3 matrix."""
    a, b = normalize(old), normalize(new)
    c = dot(a, b)
    w = sub(b, scaled(a, c))
    s = norm(w)
    degenerate = not s > 1e-14
    if degenerate:
        w = any_perpendicular(a)
    w = sub(w, scaled(a, dot(w, a)))
    e = divided_by_norm(w)
    t = float(np.arctan2(0.0 if degenerate else s, c))
    cl, st = float(np.cos(t)) - 1.0, float(np.sin(t))
    rows = []
    for eye, ai, ei in zip(EYE, a, e):  # written out along j: a third less time than a nested comprehension
        rows.append([cl * (ai * a[0] + ei * e[0]) + eye[0] + st * (ei * a[0] - ai * e[0]),
                     cl * (ai * a[1] + ei * e[1]) + eye[1] + st * (ei * a[1] - ai * e[1]),
                     cl * (ai * a[2] + ei * e[2]) + eye[2] + st * (ei * a[2] - ai * e[2])])
    return rows


def apply_matrix(m, v):
    """geometry.apply_matrix for one matrix and vector (its einsum, along contiguous rows)."""
    return [0.0 + ((r[0] * v[0] + r[2] * v[2]) + r[1] * v[1]) for r in m]


def apply_to_points(m, points):
    """Points (rows) through the matrix m, as einsum('bij,bkj->bki') computes them (along contiguous rows)."""
    return [[0.0 + ((r[0] * p[0] + r[2] * p[2]) + r[1] * p[1]) for r in m] for p in points]


def matmul(a, b):
    """3x3 a @ b, as einsum('bij,bjk->bik') computes it (down b's strided columns: in order)."""
    b0, b1, b2 = b
    return [[0.0 + ((r[0] * b0[k] + r[1] * b1[k]) + r[2] * b2[k]) for k in (0, 1, 2)] for r in a]
