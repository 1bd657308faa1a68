"""reach_balls' nearest points for one frame in plain Python floats (Adjust Pose and Live solve one frame).

On one frame numpy's per-call cost is nearly all a call costs (~0.4 ms for four balls); these functions do the
same floating-point operations in the same order as the numpy path (a three-term sum as (x0 + x1) + x2, as numpy
adds a 3-vector's components), so they return the same bits (tests/solver/test_reach_balls_plain.py). Vectors
are 3-tuples; a candidate that the numpy path marks invalid is not computed at all."""

import math
from itertools import combinations

_X = (1.0, 0.0, 0.0)
_INF = math.inf


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _scaled(v, s):
    return (v[0] * s, v[1] * s, v[2] * s)


def _divided(v, s):
    return (v[0] / s, v[1] / s, v[2] / s)


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(v):
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _any_perpendicular(v):
    """geometry.any_perpendicular: crossed with the axis of the smallest |component| (numpy's argmin: the first
    NaN, else the first smallest)."""
    mags = [abs(c) for c in v]
    nans = [k for k, m in enumerate(mags) if m != m]
    k = nans[0] if nans else mags.index(min(mags))
    p = _cross(v, ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))[k])
    return _divided(p, _norm(p))


def _inside(x, centres, radii, active):
    """reach_balls._inside for one point."""
    for c, r, on in zip(centres, radii, active):
        if on and not _norm(_sub(x, c)) <= r * (1.0 + 1e-12) + 1e-12:
            return False
    return True


def _projection(p, c, r):
    """project_onto_balls for one point and one ball."""
    d = _sub(p, c)
    dist = _norm(d)
    if dist > r:
        return _add(c, _scaled(d, r / dist))
    return p


def _circle_point(point, c1, r1, c2, r2):
    """reach_balls._circle_point for one frame; None where the numpy path marks it invalid."""
    axis = _sub(c2, c1)
    d = _norm(axis)
    if not d > 0.0:
        return None
    u = _divided(axis, d)
    a = (d * d + r1 * r1 - r2 * r2) / (2.0 * d)
    h2 = r1 * r1 - a * a
    if not h2 >= 0.0:
        return None
    h = math.sqrt(h2)
    m = _add(c1, _scaled(u, a))
    w = _sub(point, m)
    w = _sub(w, _scaled(u, _dot(w, u)))
    w = _sub(w, _scaled(u, _dot(w, u)))
    wn = _norm(w)
    w = _divided(w, wn) if wn > 1e-15 else _any_perpendicular(u)
    return _add(m, _scaled(w, h))


def _sphere_triple(c1, r1, c2, r2, c3, r3):
    """reach_balls._sphere_triple for one frame: its two points, or None where the numpy path marks them
    invalid."""
    ex_v = _sub(c2, c1)
    d = _norm(ex_v)
    if not d > 0.0:
        return None
    ex = _divided(ex_v, d)
    v3 = _sub(c3, c1)
    i = _dot(ex, v3)
    ey_v = _sub(v3, _scaled(ex, i))
    j = _norm(ey_v)
    if not j > 1e-12 * max(d, 1e-300):
        return None
    ey = _divided(ey_v, j)
    ez = _cross(ex, ey)
    x = (r1 * r1 - r2 * r2 + d * d) / (2.0 * d)
    y = (r1 * r1 - r3 * r3 + i * i + j * j) / (2.0 * j) - i / j * x
    z2 = r1 * r1 - x * x - y * y
    if not z2 >= 0.0:
        return None
    z = math.sqrt(z2)
    base = _add(_add(c1, _scaled(ex, x)), _scaled(ey, y))
    return _add(base, _scaled(ez, z)), _sub(base, _scaled(ez, z))


def _nearest_valid(p, cands, centres, radii, active):
    """reach_balls._nearest_valid for one frame over the valid candidates in order (the first on a tie):
    (best, distance), (p, inf) where none lies in every active ball."""
    best, best_d = p, _INF
    for cand in cands:
        dist = _norm(_sub(cand, p))
        if dist < best_d and _inside(cand, centres, radii, active):
            best, best_d = cand, dist
    return best, best_d


def nearest_in_balls(p, centres, radii, active):
    """reach_balls.nearest_in_balls for one frame: p a 3-tuple, centres a list of 3-tuples, radii a list of
    floats, active a list of bools. Returns (x, feasible)."""
    if _inside(p, centres, radii, active):
        return p, True
    k = len(radii)
    cands = [_projection(p, centres[i], radii[i]) for i in range(k) if active[i]]
    for a, b in combinations(range(k), 2):
        if active[a] and active[b]:
            pt = _circle_point(p, centres[a], radii[a], centres[b], radii[b])
            if pt is not None:
                cands.append(pt)
    for a, b, c in combinations(range(k), 3):
        if active[a] and active[b] and active[c]:
            pts = _sphere_triple(centres[a], radii[a], centres[b], radii[b], centres[c], radii[c])
            if pts is not None:
                cands.extend(pts)
    best, best_d = _nearest_valid(p, cands, centres, radii, active)
    return best, best_d < _INF


def nearest_on_sphere_in_balls(p, centre, radius, centres, radii, active):
    """reach_balls.nearest_on_sphere_in_balls for one frame (arguments as nearest_in_balls', centre a 3-tuple,
    radius a float). Returns (x, found)."""
    d = _sub(p, centre)
    dn = _norm(d)
    radial = _add(centre, _scaled(d, radius / dn)) if dn > 0.0 else _add(centre, _scaled(_X, radius))
    cands = [radial]
    k = len(radii)
    for i in range(k):
        if active[i]:
            pt = _circle_point(p, centre, radius, centres[i], radii[i])
            if pt is not None:
                cands.append(pt)
    for a, b in combinations(range(k), 2):
        if active[a] and active[b]:
            pts = _sphere_triple(centre, radius, centres[a], radii[a], centres[b], radii[b])
            if pts is not None:
                cands.extend(pts)
    best, best_d = _nearest_valid(p, cands, centres, radii, active)
    return best, best_d < _INF


def sub_base_point_priority(p, centres, radii, active, priorities):
    """reach_balls.sub_base_point for one frame with variant 'priority' (priorities a list of floats, none NaN:
    the order is numpy's stable argsort of their negatives). Returns (x, feasible)."""
    x, feasible = nearest_in_balls(p, centres, radii, active)
    if feasible or not any(active):
        return x, feasible
    order = sorted(range(len(radii)), key=lambda k: -priorities[k])
    kept = [False] * len(radii)
    for k in order:
        trial = list(kept)
        trial[k] = trial[k] or active[k]
        if sum(trial) <= 1:
            kept = trial
        elif trial != list(active) and nearest_in_balls(p, centres, radii, trial)[1]:
            kept = trial
    y = p
    for k in reversed(order):
        if active[k] and not kept[k]:
            y = _projection(y, centres[k], radii[k])
    return nearest_in_balls(y, centres, radii, kept)[0], False
