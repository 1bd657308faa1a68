"""two_bone_start for a few chains in plain Python floats (an Adjust Pose or Live solve warm-starts both arms, one
row each). The arithmetic is the numpy path's, in the same order; the trigonometry and the matrix products are
numpy's own routines called on one row (numpy's arccos, sin, cos and arctan2 may round otherwise than Python's
math module on some processors, and einsum adds its three products in an order of its own), so each row gets the
bits the numpy path gives it (tests/solver/test_two_bone_start_plain.py). Rows are independent, but for one batch
step: where any row's arm must first turn toward the target, the numpy path carries every row through that turn
(the identity for the others) and builds every row's turn (raising its errors); so does this one.

Returns None where plain floats would divide by zero (a folded or zero-length chain): the numpy path then answers,
with its NaNs and errors."""

import math

import numpy as np

from .errors import SolverInputError
from .geometry import TINY

_EYE = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def two_bone_start(start, targets, axis, pole=None):
    """two_bone_start.two_bone_start on chains (b,n,3) in plain floats: (b,n,3), or None (see the module notes)."""
    try:
        return _two_bone_start(start, targets, axis, pole)
    except ZeroDivisionError:
        return None


def _two_bone_start(start, targets, axis, pole):
    m = start.shape[1] - 1
    chains = start.tolist()
    goals = targets.tolist()
    axes = axis.tolist()
    poles = [None] * len(chains) if pole is None else pole.tolist()
    a_len = [_norm(_sub(ch[m - 1], ch[m - 2])) for ch in chains]
    c_len = [_norm(_sub(ch[m], ch[m - 1])) for ch in chains]
    if m >= 3:
        reach = [_reach(ch, t, a, c, m) for ch, t, a, c in zip(chains, goals, a_len, c_len)]
        if any(r[0] for r in reach):
            for r, (need, cos_now, cos_max, arm, to_t, dist) in enumerate(reach):
                base = chains[r][0]
                turn = _reach_turn(cos_now, cos_max, arm, to_t, dist)  # every row's, as there (and its errors)
                turn = turn if need else _EYE
                chains[r] = [_add(base, p) for p in _turned(turn, [_sub(p, base) for p in chains[r]])]
                axes[r] = _applied(turn, axes[r])
    out = []
    for ch, t, ax, pl, a, c in zip(chains, goals, axes, poles, a_len, c_len):
        out.append(_bend(ch, t, ax, pl, a, c, m))
    return np.array(out, dtype=np.float64)


def _reach(chain, target, a, c, m):
    """Step 0 of two_bone_start for one chain: (whether the arm must turn, and what the turn is built from)."""
    base = chain[0]
    arm = _sub(chain[m - 2], base)
    length = _norm(arm)
    to_t = _sub(target, base)
    dist = _norm(to_t)
    reach2 = (a + c) * (1.0 - 1e-3)
    cos_max = (dist * dist + length * length - reach2 * reach2) / (2.0 * length * max(dist, 1e-300))
    cos_now = _dot(arm, to_t) / (length * max(dist, 1e-300))
    return cos_now < cos_max and dist > 0.0, cos_now, cos_max, arm, to_t, dist


def _reach_turn(cos_now, cos_max, arm, to_t, dist):
    """The turn about joint 0 (rows of a 3x3 matrix) that brings the target within the two segments' reach."""
    t_dir = tuple(x / max(dist, 1e-300) for x in to_t)
    angle_now = float(np.arccos(min(max(cos_now, -1.0), 1.0)))
    angle_ok = float(np.arccos(min(max(cos_max, -1.0), 1.0)))
    side = _cross(t_dir, arm)
    flip = 1.0 if _norm(side) <= 1e-12 else 0.0
    new_w = _rotated(t_dir, _add(side, _scaled(_any_perpendicular(t_dir), flip)), angle_ok)
    return _swing(arm, new_w if angle_now > angle_ok else arm)


def _bend(chain, target, axis, pole, a, c, m):
    """Steps 1-2 of two_bone_start for one chain (already turned toward the target if step 0 ran)."""
    pivot = chain[m - 2]
    turn = _swing(_sub(chain[m], pivot), _sub(target, pivot))
    chain = chain[:m - 2] + [_add(pivot, p) for p in _turned(turn, [_sub(p, pivot) for p in chain[m - 2:]])]
    axis = _applied(turn, axis)
    to_target = _sub(target, pivot)
    dist = _norm(to_target)
    d = min(max(dist, abs(a - c)), a + c)
    dt = tuple(x / max(dist, 1e-300) for x in to_target)
    if pole is not None and math.isfinite(pole[0]):
        toward = _cross(_sub(pole, pivot), dt)
        if _norm(toward) > 1e-9 * max(dist, 1e-300):
            axis = toward
    along = _dot(axis, dt)
    n = tuple(x - along * y for x, y in zip(axis, dt))
    n_len = _norm(n)
    ok = n_len > 1e-9
    n = tuple(x / n_len for x in n) if ok else _EYE[0]
    cos_alpha = min(max((a * a + d * d - c * c) / (2.0 * a * max(d, 1e-300)), -1.0), 1.0)
    upper = _rotated(dt, n, -float(np.arccos(cos_alpha)))
    elbow = _add(pivot, _scaled(upper, a))
    lower = _sub(target, elbow)
    ln = _norm(lower)
    lower = tuple(x / max(ln, 1e-300) for x in lower) if ln > 1e-300 else upper
    if not (ok and dist > 0.0):
        return chain
    return chain[:m - 1] + [elbow, _add(elbow, _scaled(lower, c))]


# --- geometry.py's helpers on 3-tuples, the same operations ---------------------------------------------------


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _scaled(v, s):
    return (v[0] * s, v[1] * s, v[2] * s)


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(v):
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _unit(v):
    """geometry.normalize without a fallback."""
    n = _norm(v)
    if not n > TINY:
        raise SolverInputError("cannot normalise a zero-length vector")
    return (v[0] / n, v[1] / n, v[2] / n)


def _any_perpendicular(v):
    mags = [abs(x) for x in v]
    nans = [k for k, x in enumerate(mags) if x != x]
    p = _cross(v, _EYE[nans[0] if nans else mags.index(min(mags))])
    n = _norm(p)
    return (p[0] / n, p[1] / n, p[2] / n)


def _rotated(v, axis, angle):
    """geometry.rotate_about_axis for one vector."""
    k = _unit(axis)
    cos_a, sin_a = float(np.cos(angle)), float(np.sin(angle))
    kv, along = _cross(k, v), _dot(k, v) * (1.0 - cos_a)
    return (v[0] * cos_a + kv[0] * sin_a + k[0] * along, v[1] * cos_a + kv[1] * sin_a + k[1] * along,
            v[2] * cos_a + kv[2] * sin_a + k[2] * along)


def _swing(old, new):
    """geometry.swing_rotation for one pair (its few-rotations form): the rows of the 3x3 matrix."""
    a, b = _unit(old), _unit(new)
    c = _dot(a, b)
    w = _sub(b, _scaled(a, c))
    s = _norm(w)
    degenerate = not s > 1e-14
    if degenerate:
        w = _any_perpendicular(a)
    w = _sub(w, _scaled(a, _dot(w, a)))
    wn = _norm(w)
    e = (w[0] / wn, w[1] / wn, w[2] / wn)
    t = float(np.arctan2(0.0 if degenerate else s, c))
    cl, st = float(np.cos(t)) - 1.0, float(np.sin(t))
    return [[cl * (a[i] * a[j] + e[i] * e[j]) + _EYE[i][j] + st * (e[i] * a[j] - a[i] * e[j]) for j in (0, 1, 2)]
            for i in (0, 1, 2)]


def _turned(turn, points):
    """Points (rows) through the matrix `turn`, as two_bone_start's einsum('bij,bkj->bki') computes them."""
    return np.einsum("bij,bkj->bki", np.array([turn]), np.array([points])).tolist()[0]


def _applied(turn, v):
    """geometry.apply_matrix for one matrix and vector (its einsum)."""
    return np.einsum("...ij,...j->...i", np.array([turn]), np.array([v])).tolist()[0]
