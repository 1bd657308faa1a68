"""One frame or many: the only module that knows which.

A calculation is written once: a number is a Python float (one frame) or a float64 array (F,) (F frames, one lane
each), a 3-vector a tuple of floats or an array (F,3) (maths/vectors.py). `+ - * /`, abs, comparisons and sqrt
round the same on a float and on an array's element, and the trigonometry calls numpy's routine on the one value
as on the many, so a frame solved alone equals its row of a batch by construction. What differs between the two
lives here: choosing per lane (where, pick), asking about all lanes (any_, all_), a division that never raises,
and `run`, which decides how a kernel meets its (F,3) arrays: up to FEW frames one frame at a time in plain
floats (numpy's per-call cost is most of a one-frame solve), beyond that on the arrays."""

import math

import numpy as np

# Up to this many frames a kernel runs frame by frame on Python floats.
FEW = 4


_ARRAY = np.ndarray


def few(frames):
    """Whether `frames` problems are solved one at a time on Python floats (else together on arrays)."""
    return frames <= FEW


def many(x):
    """True when x holds a lane per frame (an array), False for one frame's float or bool."""
    return x.__class__ is _ARRAY


def where(cond, a, b):
    """a where cond, else b (per lane)."""
    if cond.__class__ is _ARRAY:
        return np.where(cond, a, b)
    return a if cond else b


def pick(cond, u, v):
    """The vector u where cond, else v (per lane; vectors as maths/vectors.py has them)."""
    if cond.__class__ is _ARRAY:
        return np.where(cond[..., None], u, v)
    return u if cond else v


def any_(cond):
    """Whether cond holds in some lane."""
    if cond.__class__ is bool:
        return cond
    return np.count_nonzero(cond) != 0 if cond.__class__ is _ARRAY else bool(cond)


def all_(cond):
    """Whether cond holds in every lane."""
    return np.count_nonzero(cond) == cond.size if cond.__class__ is _ARRAY else bool(cond)


def not_(cond):
    return ~cond if cond.__class__ is _ARRAY else not cond


def isnan(x):
    return np.isnan(x) if x.__class__ is _ARRAY else x != x


def sqrt(x):
    if x.__class__ is _ARRAY:
        return np.sqrt(x)
    if not x < 0.0:
        return math.sqrt(x)
    with np.errstate(invalid="ignore"):
        return float(np.sqrt(x))


def divide(a, b):
    """a / b, as numpy divides (inf or NaN where b is zero or the quotient overflows, never an exception)."""
    if a.__class__ is _ARRAY or b.__class__ is _ARRAY:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return np.divide(a, b)
    if b != 0.0:
        return a / b
    with np.errstate(divide="ignore", invalid="ignore"):  # numpy's inf or NaN, its sign bits included
        return float(np.float64(a) / b)


def maximum(x, c):
    """The larger of x and c per lane, NaN where either is NaN (as numpy's)."""
    if x.__class__ is _ARRAY or c.__class__ is _ARRAY:
        return np.maximum(x, c)
    return x if x >= c or x != x else c


def minimum(x, c):
    """The smaller of x and c per lane, NaN where either is NaN (as numpy's)."""
    if x.__class__ is _ARRAY or c.__class__ is _ARRAY:
        return np.minimum(x, c)
    return x if x <= c or x != x else c


def clip(x, lo, hi):
    """x within [lo, hi] (NaN stays NaN)."""
    return np.clip(x, lo, hi) if _ARRAY in (x.__class__, lo.__class__, hi.__class__) else min(max(x, lo), hi)


def isfinite(x):
    return np.isfinite(x) if x.__class__ is _ARRAY else math.isfinite(x)


def arccos(x):
    return np.arccos(x) if x.__class__ is _ARRAY else float(np.arccos(x))


def hypot(x, y):
    return np.hypot(x, y) if x.__class__ is _ARRAY or y.__class__ is _ARRAY else float(np.hypot(x, y))


def remainder(x, y):
    return np.remainder(x, y) if x.__class__ is _ARRAY or y.__class__ is _ARRAY else float(np.remainder(x, y))


def arctan2(y, x):
    if y.__class__ is _ARRAY or x.__class__ is _ARRAY:
        return np.arctan2(y, x)
    return float(np.arctan2(y, x))


def cos(x):
    return np.cos(x) if x.__class__ is _ARRAY else float(np.cos(x))


def sin(x):
    return np.sin(x) if x.__class__ is _ARRAY else float(np.sin(x))


def by_rows(kernel, P, rows, *per_row, kinds=(), floats=True):
    """kernel(pose, rows, *per_row) -> (pose, *values) on the problems `rows` (an index array) of P (B,n,3), which
    takes the poses it returns. Up to FEW problems (and where `floats`) each alone on its floats: pose a list of
    joint tuples, rows an int, per_row values (arrays (b,)) as Python scalars; else all at once on arrays: P[rows],
    the index array, per_row as they are. Returns the values, arrays of the dtypes `kinds` per problem. Where a
    problem's floats would divide by zero (numpy's inf or NaN), the arrays take every problem."""
    if floats and 0 < rows.size <= FEW:
        lists = [np.broadcast_to(v, rows.shape).tolist() for v in per_row]
        try:
            out = [kernel([tuple(p) for p in P[r].tolist()], r, *[v[k] for v in lists])
                   for k, r in enumerate(rows.tolist())]
        except ZeroDivisionError:
            out = None
        if out is not None:
            P[rows] = [one[0] for one in out]
            return tuple(np.array([one[k] for one in out], dtype=kind) for k, kind in enumerate(kinds, 1))
    pose, *values = kernel(P[rows], rows, *[np.broadcast_to(v, rows.shape) for v in per_row])
    P[rows] = pose
    return tuple(values)


def run(kernel, arrays, *rest, values=(), outputs=1):
    """kernel(*vectors, *values, *rest) on `arrays` (F,3) (a vector each), (F,n,3) (a list of n vectors) or None
    (passed as None) and `values` (F,) (a number each) or (F,m) (a list of m numbers). Returns its vector, list of
    vectors, matrix or number as (F,3), (F,n,3), (F,3,3) or (F,) (with outputs > 1, the kernel returns that many,
    each so). Up to FEW frames each frame alone in floats, else every frame at once on arrays (...,3), dividing
    as numpy does without a warning."""
    frames = next(a for a in arrays if a is not None).shape[0]
    if 0 < frames <= FEW:
        out = [kernel(*[_row(a, f) for a in arrays], *[a[f].tolist() for a in values], *rest) for f in range(frames)]
        if outputs == 1:
            return np.array(out, dtype=np.float64)
        return tuple(np.array([o[k] for o in out]) for k in range(outputs))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = kernel(*[a if a is None or a.ndim == 2 else list(a.transpose(1, 0, 2)) for a in arrays],
                     *[a if a.ndim == 1 else list(a.T) for a in values], *rest)
    if outputs == 1:
        return _gathered(out, frames)
    return tuple(_gathered(o, frames) for o in out)


def _gathered(out, frames):
    """A kernel's output on many frames as one array (F,...): a list's items side by side, constants repeated."""
    if isinstance(out, list):
        return np.stack([_gathered(v, frames) for v in out], axis=1)
    if out.__class__ is _ARRAY:
        return out.copy()
    out = np.asarray(out)
    return np.broadcast_to(out, (frames,) + out.shape).copy()


def _row(a, f):
    if a is None:
        return None
    r = a[f].tolist()
    return tuple(r) if a.ndim == 2 else [tuple(p) for p in r]
