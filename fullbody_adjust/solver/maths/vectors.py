"""3-vectors on components (x, y, z), each a float for one frame or an (F,) array for F frames (maths/lanes.py): the
helpers of maths/geometry.py written once for both. Sums run in order, (x0 + x1) + x2, as geometry.dot adds.

The helpers a kernel of many vectors calls most (sub, add, scaled, divided, dot, norm, cross, any_perpendicular)
also take whole arrays (...,3) (numbers then (...) arrays): the same operations in the same order on a third of the
numpy calls, for the kernels run on many rows at once (the joint limits in FABRIK's passes)."""

import math

import numpy as np

from . import geometry, lanes
from ..errors import SolverInputError
from .geometry import TINY

_ARRAY = np.ndarray

EYE = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def sub(a, b):
    if a.__class__ is _ARRAY:
        return a - b
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def add(a, b):
    if a.__class__ is _ARRAY:
        return a + b
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def neg(a):
    if a.__class__ is _ARRAY:
        return -a
    return (-a[0], -a[1], -a[2])


def scaled(v, s):
    if v.__class__ is _ARRAY:
        return v * s[..., None] if s.__class__ is _ARRAY else v * s
    return (v[0] * s, v[1] * s, v[2] * s)


def divided(v, s):
    """v / s, inf or NaN where s is zero (as numpy divides)."""
    if s.__class__ is float and s != 0.0 and v.__class__ is not _ARRAY:
        return (v[0] / s, v[1] / s, v[2] / s)
    if v.__class__ is _ARRAY:
        return v / s[..., None] if s.__class__ is _ARRAY else v / s  # as geometry's callers divide
    if not lanes.many(s) and s != 0.0:
        return (v[0] / s, v[1] / s, v[2] / s)
    return (lanes.divide(v[0], s), lanes.divide(v[1], s), lanes.divide(v[2], s))


def dot(a, b):
    if a.__class__ is _ARRAY:
        return geometry.dot(a, b)
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def norm(v):
    if v.__class__ is _ARRAY:
        return geometry.norm(v)
    s = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    return math.sqrt(s) if s.__class__ is float else lanes.sqrt(s)  # a float's sum of squares: never negative


def cross(a, b):
    if a.__class__ is _ARRAY:
        return geometry.cross(a, b)
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def normalize(v, fallback=None):
    """geometry.normalize: unit v; where v has no length the fallback (normalised itself); SolverInputError
    where there is neither."""
    n = norm(v)
    zero = lanes.not_(n > TINY)
    if not lanes.any_(zero):
        return (v[0] / n, v[1] / n, v[2] / n)
    if fallback is None:
        raise SolverInputError("cannot normalise a zero-length vector")
    safe = lanes.pick(zero, fallback, v)
    n = norm(safe)
    if not lanes.all_(n > TINY):
        raise SolverInputError("cannot normalise a zero-length vector (fallback is zero too)")
    return (safe[0] / n, safe[1] / n, safe[2] / n)


def any_perpendicular(v):
    """geometry.any_perpendicular: v crossed with the coordinate axis of its smallest |component| (numpy's argmin:
    the first NaN, else the first smallest), divided by its length."""
    if v.__class__ is _ARRAY:
        return geometry.any_perpendicular(v)
    ax, ay, az = abs(v[0]), abs(v[1]), abs(v[2])
    nx, ny, nz = lanes.isnan(ax), lanes.isnan(ay), lanes.isnan(az)
    first = nx | (lanes.not_(ny | nz) & (ax <= ay) & (ax <= az))
    second = lanes.not_(first) & (ny | (lanes.not_(nz) & (ay <= az)))
    third = lanes.not_(first | second)
    e = (lanes.where(first, 1.0, 0.0), lanes.where(second, 1.0, 0.0), lanes.where(third, 1.0, 0.0))
    p = cross(v, e)
    return divided(p, norm(p))


def rotate_about_axis(v, axis, angle):
    """geometry.rotate_about_axis: v turned about axis (need not be unit) by angle (Rodrigues)."""
    k = normalize(axis)
    cos_a, sin_a = lanes.cos(angle), lanes.sin(angle)
    kv, along = cross(k, v), dot(k, v) * (1.0 - cos_a)
    return (v[0] * cos_a + kv[0] * sin_a + k[0] * along, v[1] * cos_a + kv[1] * sin_a + k[1] * along,
            v[2] * cos_a + kv[2] * sin_a + k[2] * along)


def swing_rotation(old, new):
    """geometry.swing_rotation: the minimal rotation taking direction old to new, as its three rows."""
    a, b = normalize(old), normalize(new)
    c = dot(a, b)
    w = sub(b, scaled(a, c))
    s = norm(w)
    degenerate = lanes.not_(s > 1e-14)
    if lanes.any_(degenerate):
        w = lanes.pick(degenerate, any_perpendicular(a), w)
    w = sub(w, scaled(a, dot(w, a)))
    e = divided(w, norm(w))
    t = lanes.arctan2(lanes.where(degenerate, 0.0, s), c)
    cl, st = lanes.cos(t) - 1.0, lanes.sin(t)
    rows = []
    for eye, ai, ei in zip(EYE, a, e):  # written out along j: a third less time than a nested comprehension
        rows.append((cl * (ai * a[0] + ei * e[0]) + eye[0] + st * (ei * a[0] - ai * e[0]),
                     cl * (ai * a[1] + ei * e[1]) + eye[1] + st * (ei * a[1] - ai * e[1]),
                     cl * (ai * a[2] + ei * e[2]) + eye[2] + st * (ei * a[2] - ai * e[2])))
    return tuple(rows)


def apply_matrix(m, v):
    """The matrix m (three rows) times v."""
    return (dot(m[0], v), dot(m[1], v), dot(m[2], v))


def matmul(a, b):
    """The matrix product a b (matrices as their three rows)."""
    b0, b1, b2 = b
    return tuple((r[0] * b0[0] + r[1] * b1[0] + r[2] * b2[0], r[0] * b0[1] + r[1] * b1[1] + r[2] * b2[1],
                  r[0] * b0[2] + r[1] * b1[2] + r[2] * b2[2]) for r in a)


def rotation_about(k, angle):
    """The rotation about the unit axis k by angle (Rodrigues): the rows of c I + s [k]x + (1 - c) k k'."""
    c, s = lanes.cos(angle), lanes.sin(angle)
    x, y, z = k
    t = 1.0 - c
    return ((c * 1.0 + s * 0.0 + t * (x * x), c * 0.0 + s * -z + t * (x * y), c * 0.0 + s * y + t * (x * z)),
            (c * 0.0 + s * z + t * (y * x), c * 1.0 + s * 0.0 + t * (y * y), c * 0.0 + s * -x + t * (y * z)),
            (c * 0.0 + s * -y + t * (z * x), c * 0.0 + s * x + t * (z * y), c * 1.0 + s * 0.0 + t * (z * z)))
