"""3-vectors written once for one frame and for many (maths/lanes.py): a tuple (x, y, z) of Python floats for one
frame, an array (...,3) (components on the last axis: one numpy call per operation) for many; a constant tuple
meets an array by numpy's broadcasting. A matrix is three rows, or an array (...,3,3). The arrays go through
maths/geometry.py, which does the same operations in the same order (sums run (x0 + x1) + x2), so a frame alone
equals its row of a batch."""

import math

import numpy as np

from . import geometry, lanes
from ..errors import SolverInputError
from .geometry import TINY

_ARRAY = np.ndarray
_IDENTITY = np.eye(3)

EYE = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def sub(a, b):
    if a.__class__ is _ARRAY or b.__class__ is _ARRAY:
        return np.subtract(a, b)
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def add(a, b):
    if a.__class__ is _ARRAY or b.__class__ is _ARRAY:
        return np.add(a, b)
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def neg(a):
    if a.__class__ is _ARRAY:
        return -a
    return (-a[0], -a[1], -a[2])


def scaled(v, s):
    if s.__class__ is _ARRAY:
        return np.multiply(v, s[..., None])
    if v.__class__ is _ARRAY:
        return v * s
    return (v[0] * s, v[1] * s, v[2] * s)


def divided(v, s):
    """v / s, inf or NaN where s is zero (as numpy divides; lanes.run's many frames divide under np.errstate)."""
    if s.__class__ is _ARRAY:
        return np.divide(v, s[..., None])
    if v.__class__ is _ARRAY:
        return v / s
    if s != 0.0:
        return (v[0] / s, v[1] / s, v[2] / s)
    return (lanes.divide(v[0], s), lanes.divide(v[1], s), lanes.divide(v[2], s))


def dot(a, b):
    if a.__class__ is _ARRAY or b.__class__ is _ARRAY:
        return geometry.dot(a, b)
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def norm(v):
    if v.__class__ is _ARRAY:
        return geometry.norm(v)
    s = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    return math.sqrt(s) if s.__class__ is float else lanes.sqrt(s)  # a float's sum of squares: never negative


def cross(a, b):
    if a.__class__ is _ARRAY or b.__class__ is _ARRAY:
        return geometry.cross(a, b)
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def normalize(v, fallback=None):
    """geometry.normalize: unit v; where v has no length the fallback (normalised itself); SolverInputError
    where there is neither."""
    if v.__class__ is _ARRAY:
        return geometry.normalize(v, fallback)
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
    return divided(safe, n)


def any_perpendicular(v):
    """geometry.any_perpendicular: v crossed with the coordinate axis of its smallest |component| (numpy's argmin:
    the first NaN, else the first smallest), divided by its length."""
    if v.__class__ is _ARRAY:
        return geometry.any_perpendicular(v)
    ax, ay, az = abs(v[0]), abs(v[1]), abs(v[2])
    nx, ny, nz = ax != ax, ay != ay, az != az
    first = nx or (not (ny or nz) and ax <= ay and ax <= az)
    e = EYE[0] if first else EYE[1] if ny or (not nz and ay <= az) else EYE[2]
    p = cross(v, e)
    return divided(p, norm(p))


def rotate_about_axis(v, axis, angle):
    """geometry.rotate_about_axis: v turned about axis (need not be unit) by angle (Rodrigues)."""
    if v.__class__ is _ARRAY or axis.__class__ is _ARRAY or angle.__class__ is _ARRAY:
        return geometry.rotate_about_axis(v, axis, angle)
    k = normalize(axis)
    cos_a, sin_a = lanes.cos(angle), lanes.sin(angle)
    kv, along = cross(k, v), dot(k, v) * (1.0 - cos_a)
    return (v[0] * cos_a + kv[0] * sin_a + k[0] * along, v[1] * cos_a + kv[1] * sin_a + k[1] * along,
            v[2] * cos_a + kv[2] * sin_a + k[2] * along)


def swing_rotation(old, new):
    """geometry.swing_rotation: the minimal rotation taking direction old to new, as its three rows."""
    if old.__class__ is _ARRAY or new.__class__ is _ARRAY:
        return geometry.swing_rotation(old, new)
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
    if m.__class__ is _ARRAY or v.__class__ is _ARRAY:
        return geometry.apply_matrix(m, v)
    return (dot(m[0], v), dot(m[1], v), dot(m[2], v))


def matmul(a, b):
    """The matrix product a b (matrices as their three rows): entry (i, j) summed in order over k."""
    if a.__class__ is _ARRAY or b.__class__ is _ARRAY:
        a, b = np.asarray(a)[..., :, :, None], np.asarray(b)[..., None, :, :]
        return a[..., 0, :] * b[..., 0, :] + a[..., 1, :] * b[..., 1, :] + a[..., 2, :] * b[..., 2, :]
    b0, b1, b2 = b
    return tuple((r[0] * b0[0] + r[1] * b1[0] + r[2] * b2[0], r[0] * b0[1] + r[1] * b1[1] + r[2] * b2[1],
                  r[0] * b0[2] + r[1] * b1[2] + r[2] * b2[2]) for r in a)


def rotation_about(k, angle):
    """The rotation about the unit axis k by angle (Rodrigues): the rows of c I + s [k]x + (1 - c) k k'."""
    c, s = lanes.cos(angle), lanes.sin(angle)
    if k.__class__ is _ARRAY or c.__class__ is _ARRAY:
        k, (c, s) = np.asarray(k), (np.asarray(c)[..., None, None], np.asarray(s)[..., None, None])
        x, y, z = k[..., 0], k[..., 1], k[..., 2]
        zero = np.zeros_like(x)
        skew = np.stack((zero, -z, y, z, zero, -x, -y, x, zero), -1).reshape(x.shape + (3, 3))
        return c * _IDENTITY + s * skew + (1.0 - c) * (k[..., :, None] * k[..., None, :])
    x, y, z = k
    t = 1.0 - c
    return ((c * 1.0 + s * 0.0 + t * (x * x), c * 0.0 + s * -z + t * (x * y), c * 0.0 + s * y + t * (x * z)),
            (c * 0.0 + s * z + t * (y * x), c * 1.0 + s * 0.0 + t * (y * y), c * 0.0 + s * -x + t * (y * z)),
            (c * 0.0 + s * -y + t * (z * x), c * 0.0 + s * x + t * (z * y), c * 1.0 + s * 0.0 + t * (z * z)))
