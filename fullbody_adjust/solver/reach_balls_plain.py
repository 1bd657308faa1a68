"""reach_balls' nearest points for one frame in plain Python floats (Adjust Pose and Live solve one frame).

On one frame numpy's per-call cost is nearly all a call costs (~0.4 ms for four balls); these functions do the
same floating-point operations in the same order as the numpy path (geometry_plain.py), so they return the same
bits (tests/solver/test_reach_balls_plain.py). Vectors are 3-tuples; a candidate that the numpy path marks invalid
is not computed at all."""

import math
from itertools import combinations

from . import geometry_plain as g

_INF = math.inf
# A point nearer a sphere's centre than this has no usable direction to it: the squares of its offset's
# components fall among the subnormal numbers, its length loses digits, and the radial projection lands off the
# sphere (a point 4e-161 from the centre landed 2.6e-4 off a unit sphere). Every point of the sphere is then as
# near as any other, up to this distance.
NEAR_CENTRE = 1e-150


def _inside(x, centres, radii, active):
    """reach_balls._inside for one point."""
    for c, r, on in zip(centres, radii, active):
        if on and not g.norm(g.sub(x, c)) <= r * (1.0 + 1e-12) + 1e-12:
            return False
    return True


def _projection(p, c, r):
    """project_onto_balls for one point and one ball."""
    d = g.sub(p, c)
    dist = g.norm(d)
    if dist > r:
        return g.add(c, g.scaled(d, r / dist))
    return p


def _circle_point(point, c1, r1, c2, r2):
    """reach_balls._circle_point for one frame; None where the numpy path marks it invalid."""
    axis = g.sub(c2, c1)
    d = g.norm(axis)
    if not d > 0.0:
        return None
    u = g.divided(axis, d)
    a = (d * d + r1 * r1 - r2 * r2) / (2.0 * d)
    h2 = r1 * r1 - a * a
    if not h2 >= 0.0:
        return None
    h = math.sqrt(h2)
    m = g.add(c1, g.scaled(u, a))
    w = g.sub(point, m)
    w = g.sub(w, g.scaled(u, g.dot(w, u)))
    w = g.sub(w, g.scaled(u, g.dot(w, u)))
    wn = g.norm(w)
    w = g.divided(w, wn) if wn > 1e-15 else g.any_perpendicular(u)
    return g.add(m, g.scaled(w, h))


def _sphere_triple(c1, r1, c2, r2, c3, r3):
    """reach_balls._sphere_triple for one frame: its two points, or None where the numpy path marks them
    invalid."""
    ex_v = g.sub(c2, c1)
    d = g.norm(ex_v)
    if not d > 0.0:
        return None
    ex = g.divided(ex_v, d)
    v3 = g.sub(c3, c1)
    i = g.dot(ex, v3)
    ey_v = g.sub(v3, g.scaled(ex, i))
    j = g.norm(ey_v)
    if not j > 1e-12 * max(d, 1e-300):
        return None
    ey = g.divided(ey_v, j)
    ez = g.cross(ex, ey)
    x = (r1 * r1 - r2 * r2 + d * d) / (2.0 * d)
    y = (r1 * r1 - r3 * r3 + i * i + j * j) / (2.0 * j) - i / j * x
    z2 = r1 * r1 - x * x - y * y
    if not z2 >= 0.0:
        return None
    z = math.sqrt(z2)
    base = g.add(g.add(c1, g.scaled(ex, x)), g.scaled(ey, y))
    return g.add(base, g.scaled(ez, z)), g.sub(base, g.scaled(ez, z))


def _nearest_valid(p, cands, centres, radii, active):
    """reach_balls._nearest_valid for one frame over the valid candidates in order (the first on a tie):
    (best, distance), (p, inf) where none lies in every active ball."""
    best, best_d = p, _INF
    for cand in cands:
        dist = g.norm(g.sub(cand, p))
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
    d = g.sub(p, centre)
    dn = g.norm(d)
    radial = g.add(centre, g.scaled(d, radius / dn)) if dn > NEAR_CENTRE \
        else g.add(centre, g.scaled(g.EYE[0], radius))
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
