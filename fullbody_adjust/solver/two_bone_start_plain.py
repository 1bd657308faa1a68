"""two_bone_start for a few chains in plain Python floats (an Adjust Pose or Live solve warm-starts both arms, one
row each). The arithmetic is the numpy path's, in the same order, the trigonometry and the matrix products numpy's
own routines called on one row (geometry_plain.py), so each row gets the bits the numpy path gives it
(tests/solver/test_two_bone_start_plain.py). Rows are independent, but for one batch step: where any row's arm
must first turn toward the target, the numpy path carries every row through that turn (the identity for the
others) and builds every row's turn (raising its errors); so does this one.

Returns None where plain floats would divide by zero (a folded or zero-length chain): the numpy path then answers,
with its NaNs and errors."""

import math

import numpy as np

from . import geometry_plain as g


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
    a_len = [g.norm(g.sub(ch[m - 1], ch[m - 2])) for ch in chains]
    c_len = [g.norm(g.sub(ch[m], ch[m - 1])) for ch in chains]
    if m >= 3:
        reach = [_reach(ch, t, a, c, m) for ch, t, a, c in zip(chains, goals, a_len, c_len)]
        if any(r[0] for r in reach):
            for r, (need, cos_now, cos_max, arm, to_t, dist) in enumerate(reach):
                base = chains[r][0]
                turn = _reach_turn(cos_now, cos_max, arm, to_t, dist)  # every row's, as there (and its errors)
                turn = turn if need else g.EYE
                turned = g.apply_to_points(turn, [g.sub(p, base) for p in chains[r]])
                chains[r] = [g.add(base, p) for p in turned]
                axes[r] = g.apply_matrix(turn, axes[r])
    out = []
    for ch, t, ax, pl, a, c in zip(chains, goals, axes, poles, a_len, c_len):
        out.append(_bend(ch, t, ax, pl, a, c, m))
    return np.array(out, dtype=np.float64)


def _reach(chain, target, a, c, m):
    """Step 0 of two_bone_start for one chain: (whether the arm must turn, and what the turn is built from)."""
    base = chain[0]
    arm = g.sub(chain[m - 2], base)
    length = g.norm(arm)
    to_t = g.sub(target, base)
    dist = g.norm(to_t)
    reach2 = (a + c) * (1.0 - 1e-3)
    cos_max = (dist * dist + length * length - reach2 * reach2) / (2.0 * length * max(dist, 1e-300))
    cos_now = g.dot(arm, to_t) / (length * max(dist, 1e-300))
    return cos_now < cos_max and dist > 0.0, cos_now, cos_max, arm, to_t, dist


def _reach_turn(cos_now, cos_max, arm, to_t, dist):
    """The turn about joint 0 (rows of a 3x3 matrix) that brings the target within the two segments' reach."""
    t_dir = g.divided(to_t, max(dist, 1e-300))
    angle_now = float(np.arccos(min(max(cos_now, -1.0), 1.0)))
    angle_ok = float(np.arccos(min(max(cos_max, -1.0), 1.0)))
    side = g.cross(t_dir, arm)
    flip = 1.0 if g.norm(side) <= 1e-12 else 0.0
    new_w = g.rotate_about_axis(t_dir, g.add(side, g.scaled(g.any_perpendicular(t_dir), flip)), angle_ok)
    return g.swing_rotation(arm, new_w if angle_now > angle_ok else arm)


def _bend(chain, target, axis, pole, a, c, m):
    """Steps 1-2 of two_bone_start for one chain (already turned toward the target if step 0 ran)."""
    pivot = chain[m - 2]
    turn = g.swing_rotation(g.sub(chain[m], pivot), g.sub(target, pivot))
    swung = g.apply_to_points(turn, [g.sub(p, pivot) for p in chain[m - 2:]])
    chain = chain[:m - 2] + [g.add(pivot, p) for p in swung]
    axis = g.apply_matrix(turn, axis)
    to_target = g.sub(target, pivot)
    dist = g.norm(to_target)
    d = min(max(dist, abs(a - c)), a + c)
    dt = g.divided(to_target, max(dist, 1e-300))
    if pole is not None and math.isfinite(pole[0]):
        toward = g.cross(g.sub(pole, pivot), dt)
        if g.norm(toward) > 1e-9 * max(dist, 1e-300):
            axis = toward
    n = g.sub(axis, g.scaled(dt, g.dot(axis, dt)))
    n_len = g.norm(n)
    ok = n_len > 1e-9
    n = g.divided(n, n_len) if ok else g.EYE[0]
    cos_alpha = min(max((a * a + d * d - c * c) / (2.0 * a * max(d, 1e-300)), -1.0), 1.0)
    upper = g.rotate_about_axis(dt, n, -float(np.arccos(cos_alpha)))
    elbow = g.add(pivot, g.scaled(upper, a))
    lower = g.sub(target, elbow)
    ln = g.norm(lower)
    lower = g.divided(lower, max(ln, 1e-300)) if ln > 1e-300 else upper
    if not (ok and dist > 0.0):
        return chain
    return chain[:m - 1] + [elbow, g.add(elbow, g.scaled(lower, c))]
