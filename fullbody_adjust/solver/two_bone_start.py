"""Warm start of a hinged limb (elbow, knee) before its chain solve: the last two segments placed by the
two-bone solution in the plane of the start hinge axis (see limb_placement.LimbPlacement._solve).

Two implementations of the same steps: numpy over a batch of chains, and plain Python floats for one chain
(a single pose: Adjust Pose, Live), where numpy's per-call overhead would cost ten times the arithmetic. They
agree within rounding (tests/solver/test_two_bone_start.py).
"""

import math

import numpy as np

from .errors import SolverInputError
from .geometry import TINY, any_perpendicular, apply_matrix, cross, dot, norm, rotate_about_axis, swing_rotation

_EYE = np.eye(3)


def two_bone_start(start, targets, axis, pole=None):
    """Place the last two segments of chains (b,n,3) so the end meets `targets` (b,3) with the last joint's
    hinge (axis (b,3) at the start pose) bending to its positive side; where `pole` (b,3) is given (finite),
    the middle joint bends toward it instead, in the plane of the two segments' root, the target and the pole
    (as Blender's IK pole). Rigid turns only, smallest first:
      0. (chains with segments before the two, e.g. a clavicle) if the target is beyond the two segments'
         reach, turn the whole chain about joint 0 by the least angle that brings it within reach;
      1. swing the two segments about their root (shoulder/hip) so the end points at the target;
      2. turn the upper segment about the hinge axis (made perpendicular to root -> target) so the end lies
         at the target's distance (law of cosines; out-of-range distances are clamped: FABRIK reports them).
    """
    if start.shape[0] == 1:
        return _one_chain(start[0].tolist(), targets[0].tolist(), axis[0].tolist(),
                          None if pole is None else pole[0].tolist())[None]
    m = start.shape[1] - 1
    out = start.copy()
    a = norm(out[:, m - 1] - out[:, m - 2])
    c = norm(out[:, m] - out[:, m - 1])
    if m >= 3:
        base = out[:, 0]
        arm = out[:, m - 2] - base  # joint 0 -> root of the two segments, turned as one rigid piece
        length = norm(arm)
        to_t = targets - base
        dist = norm(to_t)
        reach2 = (a + c) * (1.0 - 1e-3)
        # Pivot p = base + length * w is within reach2 of the target iff w . t_dir >= cos_max.
        cos_max = (dist * dist + length * length - reach2 * reach2) / (2.0 * length * np.maximum(dist, 1e-300))
        cos_now = dot(arm, to_t) / (length * np.maximum(dist, 1e-300))
        need = (cos_now < cos_max) & (dist > 0.0)
        if np.any(need):
            t_dir = to_t / np.maximum(dist, 1e-300)[:, None]
            angle_now = np.arccos(np.clip(cos_now, -1.0, 1.0))
            angle_ok = np.arccos(np.clip(cos_max, -1.0, 1.0))
            new_w = rotate_about_axis(t_dir, cross(t_dir, arm) + (norm(cross(t_dir, arm)) <= 1e-12)[:, None]
                                      * any_perpendicular(t_dir), angle_ok)
            turn = swing_rotation(arm, np.where((angle_now > angle_ok)[:, None], new_w, arm))
            turn = np.where(need[:, None, None], turn, _EYE)
            out = base[:, None, :] + np.einsum("bij,bkj->bki", turn, out - base[:, None, :])
            axis = apply_matrix(turn, axis)
    pivot = out[:, m - 2]
    turn = swing_rotation(out[:, -1] - pivot, targets - pivot)
    out[:, m - 2:] = pivot[:, None, :] + np.einsum("bij,bkj->bki", turn, out[:, m - 2:] - pivot[:, None, :])
    axis = apply_matrix(turn, axis)
    to_target = targets - pivot
    d = np.clip(norm(to_target), np.abs(a - c), a + c)
    dt = to_target / np.maximum(norm(to_target), 1e-300)[:, None]
    if pole is not None:
        # The elbow lands at cos(alpha) dt + sin(alpha) (dt x n): toward the pole's side when n = w x dt.
        toward = cross(np.nan_to_num(pole - pivot), dt)
        use = np.isfinite(pole[:, 0]) & (norm(toward) > 1e-9 * np.maximum(norm(to_target), 1e-300))
        axis = np.where(use[:, None], toward, axis)
    n = axis - dot(axis, dt)[:, None] * dt
    ok = norm(n) > 1e-9
    # A chain without a bend plane keeps its start (below); any unit axis lets the other rows go on.
    n = np.where(ok[:, None], n / np.where(ok, norm(n), 1.0)[:, None], _EYE[0])
    cos_alpha = np.clip((a * a + d * d - c * c) / (2.0 * a * np.maximum(d, 1e-300)), -1.0, 1.0)
    # Upper segment at -alpha from root -> target about n, so the lower one bends by a positive angle.
    upper = rotate_about_axis(dt, n, -np.arccos(cos_alpha))
    elbow = pivot + a[:, None] * upper
    lower = targets - elbow
    ln = norm(lower)
    lower = np.where((ln > 1e-300)[:, None], lower / np.maximum(ln, 1e-300)[:, None], upper)
    placed = out.copy()
    placed[:, m - 1] = elbow
    placed[:, m] = elbow + c[:, None] * lower
    good = ok & (norm(to_target) > 0.0)
    return np.where(good[:, None, None], placed, out)


# --- one chain in plain floats (vectors as 3-lists) -------------------------------------------------------

def _sub(a, b):
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def _add(a, b):
    return [a[0] + b[0], a[1] + b[1], a[2] + b[2]]


def _scaled(v, k):
    return [v[0] * k, v[1] * k, v[2] * k]


def _divided(v, k):
    return [v[0] / k, v[1] / k, v[2] / k]


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(v):
    return math.sqrt(_dot(v, v))


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _unit(v):
    """geometry.normalize of one vector (no fallback)."""
    n = _norm(v)
    if not n > TINY:
        raise SolverInputError("cannot normalise a zero-length vector")
    return _divided(v, n)


def _perpendicular(v):
    """geometry.any_perpendicular of one vector."""
    k = min(range(3), key=lambda i: abs(v[i]))
    e = [0.0, 0.0, 0.0]
    e[k] = 1.0
    p = _cross(v, e)
    return _divided(p, _norm(p))


def _rotate(v, axis, angle):
    """geometry.rotate_about_axis of one vector."""
    k = _unit(axis)
    c, s = math.cos(angle), math.sin(angle)
    kv = _cross(k, v)
    along = _dot(k, v) * (1.0 - c)
    return [v[i] * c + kv[i] * s + k[i] * along for i in range(3)]


def _swing(old, new):
    """geometry.swing_rotation of one pair of directions, as rows of a 3x3 matrix."""
    a = _unit(old)
    b = _unit(new)
    c = _dot(a, b)
    w = _sub(b, _scaled(a, c))
    s = _norm(w)
    degenerate = not s > 1e-14
    if degenerate:
        w = _perpendicular(a)
    w = _sub(w, _scaled(a, _dot(w, a)))
    e2 = _divided(w, _norm(w))
    t = math.atan2(0.0 if degenerate else s, c)
    cos_less_1, sin_t = math.cos(t) - 1.0, math.sin(t)
    return [[cos_less_1 * (a[i] * a[j] + e2[i] * e2[j]) + (1.0 if i == j else 0.0)
             + sin_t * (e2[i] * a[j] - a[i] * e2[j]) for j in range(3)] for i in range(3)]


def _apply(matrix, v):
    return [_dot(row, v) for row in matrix]


def _one_chain(start, target, axis, pole):
    """two_bone_start of one chain: start (n,3), target, axis and pole (or None) as lists; returns (n,3)."""
    m = len(start) - 1
    out = [list(p) for p in start]
    a = _norm(_sub(out[m - 1], out[m - 2]))
    c = _norm(_sub(out[m], out[m - 1]))
    if m >= 3 and _norm(_sub(out[m - 2], out[0])) > 0.0:  # a chain folded onto its base has no arm to turn
        base = out[0]
        arm = _sub(out[m - 2], base)
        length = _norm(arm)
        to_t = _sub(target, base)
        dist = _norm(to_t)
        reach2 = (a + c) * (1.0 - 1e-3)
        cos_max = (dist * dist + length * length - reach2 * reach2) / (2.0 * length * max(dist, 1e-300))
        cos_now = _dot(arm, to_t) / (length * max(dist, 1e-300))
        if cos_now < cos_max and dist > 0.0:
            t_dir = _divided(to_t, max(dist, 1e-300))
            angle_now = math.acos(min(max(cos_now, -1.0), 1.0))
            angle_ok = math.acos(min(max(cos_max, -1.0), 1.0))
            about = _cross(t_dir, arm)
            if _norm(about) <= 1e-12:
                about = _add(about, _perpendicular(t_dir))
            new_w = _rotate(t_dir, about, angle_ok)
            turn = _swing(arm, new_w if angle_now > angle_ok else arm)
            out = [_add(base, _apply(turn, _sub(p, base))) for p in out]
            axis = _apply(turn, axis)
    pivot = out[m - 2]
    turn = _swing(_sub(out[-1], pivot), _sub(target, pivot))
    for i in range(m - 2, m + 1):
        out[i] = _add(pivot, _apply(turn, _sub(out[i], pivot)))
    axis = _apply(turn, axis)
    to_target = _sub(target, pivot)
    reach = _norm(to_target)
    d = min(max(reach, abs(a - c)), a + c)
    dt = _divided(to_target, max(reach, 1e-300))
    if pole is not None and math.isfinite(pole[0]):
        toward = _cross(_sub(pole, pivot), dt)
        if _norm(toward) > 1e-9 * max(reach, 1e-300):
            axis = toward
    n = _sub(axis, _scaled(dt, _dot(axis, dt)))
    size = _norm(n)
    if not (size > 1e-9 and reach > 0.0):
        return np.array(out)
    n = _divided(n, size)
    cos_alpha = min(max((a * a + d * d - c * c) / (2.0 * a * max(d, 1e-300)), -1.0), 1.0)
    upper = _rotate(dt, n, -math.acos(cos_alpha))
    elbow = _add(pivot, _scaled(upper, a))
    lower = _sub(target, elbow)
    ln = _norm(lower)
    lower = _divided(lower, max(ln, 1e-300)) if ln > 1e-300 else upper
    out[m - 1] = elbow
    out[m] = _add(elbow, _scaled(lower, c))
    return np.array(out)
