"""Warm start of a hinged limb (elbow, knee) before its chain solve: the last two segments placed by the
two-bone solution in the plane of the start hinge axis (see limb_placement.LimbPlacement._solve)."""

import numpy as np

from . import two_bone_start_plain
from .geometry import (any_perpendicular, any_set, apply_matrix, cross, dot, norm, rotate_about_axis,
                       swing_rotation)

_EYE = np.eye(3)
# Up to this many chains, plain floats (two_bone_start_plain.py: the same bits, without numpy's per-call cost).
_FEW_CHAINS = 4


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
    if len(start) <= _FEW_CHAINS:
        out = two_bone_start_plain.two_bone_start(start, targets, axis, pole)
        if out is not None:
            return out
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
        if any_set(need):
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
    given = None if pole is None else np.isfinite(pole[:, 0])
    if given is not None and any_set(given):
        # The elbow lands at cos(alpha) dt + sin(alpha) (dt x n): toward the pole's side when n = w x dt.
        toward = cross(np.where(given[:, None], pole - pivot, 0.0), dt)
        use = given & (norm(toward) > 1e-9 * np.maximum(norm(to_target), 1e-300))
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

