"""Sub-base geometry (paper §5.2.1 eq. (1) and §4.2): the nearest point of an intersection of reach balls, on a
sphere within them, and the priority variants that decide where the balls do not intersect. Written once on
components (maths/lanes.py): one frame in plain floats, many frames at once on component arrays, each candidate point
(a projection, a circle point, a three-sphere point) in turn."""

from itertools import combinations

import numpy as np

from ..maths import lanes
from ..maths import vectors as vec

# Relative slack of "inside a ball" tests on computed points (their rounding is ~1e-16 relative).
_INSIDE_SLACK = 1e-12
# A point nearer a sphere's centre than this has no usable direction to it: the squares of its offset's
# components fall among the subnormal numbers, its length loses digits, and the radial projection lands off the
# sphere (a point 4e-161 from the centre landed 2.6e-4 off a unit sphere). Every point of the sphere is then as
# near as any other, up to this distance.
NEAR_CENTRE = 1e-150
_INF = float("inf")


def project_onto_balls(points, centres, radii):
    """Nearest point of each ball to each point: (F,3), (F,K,3), (F,K) -> (F,K,3). Inside points stay exactly."""
    p = np.broadcast_to(points[:, None, :], np.shape(centres))
    return _projection(p, np.asarray(centres), np.asarray(radii))


def nearest_in_balls(points, centres, radii, active):
    """Nearest point to `points` (F,3) of the intersection of the active balls (F,K,3)/(F,K)/(F,K) bool.

    Exact (closed form), by the active-set argument: the optimum is the point itself, its projection onto one
    sphere, the nearest point of a two-sphere circle, or a three-sphere point; the nearest feasible candidate
    wins. Returns (x (F,3), feasible (F,)): feasible False where the balls have no common point (x = points).
    A point already inside every ball is returned unchanged (bit-exact)."""
    return lanes.run(_nearest_in_balls, (points, centres), values=(radii, active), outputs=2)


def nearest_on_sphere_in_balls(points, centre, radius, centres, radii, active):
    """Nearest point to `points` (F,3) on the sphere (centre (F,3), radius (F,)) that lies in every active ball
    (F,K,3)/(F,K)/(F,K). Candidates as in nearest_in_balls with the sphere always active: the radial
    projection, the sphere's circle with each ball's boundary, the two points it shares with two boundaries.
    Returns (x, found (F,))."""
    return lanes.run(_nearest_on_sphere, (points, centre, centres), values=(radius, radii, active), outputs=2)


def sub_base_point(points, centres, radii, active, priorities, variant):
    """Where a sub-base goes: the nearest point of the active balls' intersection (paper eq. (1)); where that
    is empty, the variant decides (paper §4.2):
      'weighted' (variant 1, eq. 4): priority-weighted mean of each ball's proposal (its nearest point);
      'fabrik': the unweighted mean (plain FABRIK's centroid);
      'priority' (variant 2): balls taken from the highest priority down while they still intersect; the
        others are served best effort: like solving the chains from the lowest priority to the highest, the
        point is pulled onto each dropped ball in turn (lowest first), then onto the kept intersection.
    priorities (K,): higher wins; ties keep the given order (earlier wins). Returns (x (F,3), feasible (F,))."""
    prio = np.asarray(priorities, dtype=np.float64)
    return lanes.run(_sub_base_point, (points, centres), prio.tolist(), variant, values=(radii, active), outputs=2)


def sub_base_point_in_plane(points, normals, centres, radii, active, priorities, variant):
    """sub_base_point for points held to the plane through `points` (F,3) with unit `normals` (F,3).

    The plane cuts each ball in a disc: the ball about the centre's projection onto the plane with radius
    sqrt(r^2 - d^2) (d the centre's distance from the plane) has the same points in the plane. Every such ball
    and every intersection of them is symmetric about the plane, and a convex set's nearest point to a point is
    unique, so the nearest point to a point of the plane lies in the plane: the 3-d solution on the cut balls is
    the in-plane one (the variants' projections keep to the plane the same way). The result is projected onto
    the plane once more against rounding; that only brings it nearer each centre and the point.
    Returns (x (F,3), feasible (F,), meets (F,)): meets False where the plane misses an active ball (x is then
    the nearest point of the others' cuts, not a placement to use)."""
    d = np.einsum("fkc,fc->fk", centres - points[:, None, :], normals)
    r = np.asarray(radii, dtype=np.float64)
    meets = ((np.abs(d) <= r) | ~active).all(axis=1)
    cut_centres = centres - d[..., None] * normals[:, None, :]
    cut_radii = np.sqrt(np.maximum(r * r - d * d, 0.0))
    x, feasible = sub_base_point(points, cut_centres, cut_radii, active, priorities, variant)
    x = x - np.einsum("fc,fc->f", x - points, normals)[:, None] * normals
    return x, feasible, meets


def _projection(p, c, r):
    """The nearest point of the ball (c, r) to p (p itself inside)."""
    d = vec.sub(p, c)
    dist = vec.norm(d)
    outside = dist > r
    scale = lanes.where(outside, r / lanes.where(outside, dist, 1.0), 1.0)
    return lanes.pick(outside, vec.add(c, vec.scaled(d, scale)), p)


def _inside(x, centres, radii, active):
    """x lies in every active ball, within rounding slack."""
    ok = True
    for c, r, on in zip(centres, radii, active):
        if lanes.any_(on):
            ok = ok & ((vec.norm(vec.sub(x, c)) <= r * (1.0 + _INSIDE_SLACK) + _INSIDE_SLACK) | lanes.not_(on))
            if not lanes.any_(ok):
                break  # outside in every lane
    return ok


def _circle_point(point, c1, r1, c2, r2):
    """Nearest point to `point` on the circle where spheres (c1,r1) and (c2,r2) meet, and whether there is one."""
    axis = vec.sub(c2, c1)
    d = vec.norm(axis)
    ok = d > 0.0
    safe_d = lanes.where(ok, d, 1.0)
    u = lanes.pick(ok, vec.divided(axis, safe_d), vec.EYE[0])  # concentric: no circle
    a = (d * d + r1 * r1 - r2 * r2) / (2.0 * safe_d)
    h2 = r1 * r1 - a * a
    ok = ok & (h2 >= 0.0)
    if not lanes.any_(ok):
        return point, ok  # no circle: never a candidate
    h = lanes.sqrt(lanes.maximum(h2, 0.0))
    m = vec.add(c1, vec.scaled(u, a))
    w = vec.sub(point, m)
    # Twice: for a point near the axis, the in-plane part left by one pass is so small that that pass's rounding
    # tilts it out of the plane (2e-12 off the axis tilted it 1e-4 rad, off the sphere by 2e-5).
    w = vec.sub(w, vec.scaled(u, vec.dot(w, u)))
    w = vec.sub(w, vec.scaled(u, vec.dot(w, u)))
    wn = vec.norm(w)
    # On the axis every circle point is equally near: take a deterministic one.
    along = wn > 1e-15
    if lanes.all_(along):
        w = vec.divided(w, wn)
    else:
        w = lanes.pick(along, vec.divided(w, lanes.where(along, wn, 1.0)), vec.any_perpendicular(u))
    return vec.add(m, vec.scaled(w, h)), ok


def _sphere_triple(c1, r1, c2, r2, c3, r3):
    """The two points where three spheres meet (trilateration), and whether they do."""
    ex_v = vec.sub(c2, c1)
    d = vec.norm(ex_v)
    ok = d > 0.0
    safe_d = lanes.where(ok, d, 1.0)
    ex = lanes.pick(ok, vec.divided(ex_v, safe_d), vec.EYE[0])
    v3 = vec.sub(c3, c1)
    i = vec.dot(ex, v3)
    ey_v = vec.sub(v3, vec.scaled(ex, i))
    j = vec.norm(ey_v)
    ok = ok & (j > 1e-12 * lanes.maximum(d, 1e-300))
    if not lanes.any_(ok):
        return c1, c1, ok
    safe_j = lanes.where(ok, j, 1.0)
    ey = vec.divided(ey_v, safe_j)
    ez = vec.cross(ex, ey)
    x = (r1 * r1 - r2 * r2 + d * d) / (2.0 * safe_d)
    y = (r1 * r1 - r3 * r3 + i * i + j * j) / (2.0 * safe_j) - i / safe_j * x
    z2 = r1 * r1 - x * x - y * y
    ok = ok & (z2 >= 0.0)
    if not lanes.any_(ok):
        return c1, c1, ok  # no common point: never a candidate
    z = lanes.sqrt(lanes.maximum(z2, 0.0))
    base = vec.add(vec.add(c1, vec.scaled(ex, x)), vec.scaled(ey, y))
    return vec.add(base, vec.scaled(ez, z)), vec.sub(base, vec.scaled(ez, z)), ok


def _nearest_valid(p, candidates, centres, radii, active):
    """The candidate (point, valid) nearest to p among the valid ones that lie in every active ball, the first
    one on a tie; and its distance (p and inf where none is)."""
    best, best_d = p, _INF
    for cand, valid in candidates:
        dist = vec.norm(vec.sub(cand, p))
        nearer = valid & (dist < best_d)  # (NaN is never nearer)
        if lanes.any_(nearer):
            nearer = nearer & _inside(cand, centres, radii, active)
            best, best_d = lanes.pick(nearer, cand, best), lanes.where(nearer, dist, best_d)
    return best, best_d


def _nearest_in_balls(p, centres, radii, active):
    inside = _inside(p, centres, radii, active)
    if lanes.all_(inside):
        return p, inside
    k = len(radii)
    cands = [(_projection(p, centres[i], radii[i]), active[i]) for i in range(k) if lanes.any_(active[i])]
    for a, b in combinations(range(k), 2):
        on = active[a] & active[b]
        if lanes.any_(on):
            pt, ok = _circle_point(p, centres[a], radii[a], centres[b], radii[b])
            cands.append((pt, ok & on))
    for a, b, c in combinations(range(k), 3):
        on = active[a] & active[b] & active[c]
        if lanes.any_(on):
            pt1, pt2, ok = _sphere_triple(centres[a], radii[a], centres[b], radii[b], centres[c], radii[c])
            cands += [(pt1, ok & on), (pt2, ok & on)]
    best, best_d = _nearest_valid(p, cands, centres, radii, active)
    found = best_d < _INF
    return lanes.pick(inside | lanes.not_(found), p, best), inside | found


def _nearest_on_sphere(p, centre, centres, radius, radii, active):
    d = vec.sub(p, centre)
    dn = vec.norm(d)
    away = dn > NEAR_CENTRE
    radial = vec.add(centre, vec.scaled(d, radius / lanes.where(away, dn, 1.0)))
    radial = lanes.pick(away, radial, vec.add(centre, vec.scaled(vec.EYE[0], radius)))  # any point will do
    cands = [(radial, True)]
    k = len(radii)
    for i in range(k):
        if lanes.any_(active[i]):
            pt, ok = _circle_point(p, centre, radius, centres[i], radii[i])
            cands.append((pt, ok & active[i]))
    for a, b in combinations(range(k), 2):
        on = active[a] & active[b]
        if lanes.any_(on):
            pt1, pt2, ok = _sphere_triple(centre, radius, centres[a], radii[a], centres[b], radii[b])
            cands += [(pt1, ok & on), (pt2, ok & on)]
    best, best_d = _nearest_valid(p, cands, centres, radii, active)
    return best, best_d < _INF


def _sub_base_point(p, centres, radii, active, prio, variant):
    x, feasible = _nearest_in_balls(p, centres, radii, active)
    k = len(radii)
    todo = lanes.not_(feasible) & _any(active)
    if not lanes.any_(todo):
        return x, feasible
    if variant in ("weighted", "fabrik"):
        w = [lanes.where(on, prio[i] if variant == "weighted" else 1.0, 0.0) for i, on in enumerate(active)]
        total = _sum(w)
        w = [lanes.where(total > 0.0, wi, lanes.where(on, 1.0, 0.0)) for wi, on in zip(w, active)]  # all zero
        total = _sum(w)
        y = (0.0, 0.0, 0.0)
        for i in range(k):
            y = vec.add(y, vec.scaled(_projection(p, centres[i], radii[i]), w[i]))
        y = vec.divided(y, total)
    else:
        order = sorted(range(k), key=lambda i: -prio[i])  # numpy's stable argsort of the negatives
        kept = [False] * k
        for i in order:
            trial = list(kept)
            trial[i] = trial[i] | active[i]
            if lanes.all_(_sum([lanes.where(t, 1.0, 0.0) for t in trial]) <= 1.0):
                kept = trial  # one ball (or none) always has a point
                continue
            if all(lanes.all_(t == on) for t, on in zip(trial, active)):
                continue  # all of them: these lanes are those whose balls have no common point (above)
            ok = _nearest_in_balls(p, centres, radii, trial)[1]
            kept = [lanes.where(ok, t, kk) for t, kk in zip(trial, kept)]
        y = p
        for i in reversed(order):
            dropped = active[i] & lanes.not_(kept[i])
            if lanes.any_(dropped):
                y = lanes.pick(dropped, _projection(y, centres[i], radii[i]), y)
        y = _nearest_in_balls(y, centres, radii, kept)[0]
    return lanes.pick(todo, y, x), feasible


def _any(flags):
    out = False
    for f in flags:
        out = out | f
    return out


def _sum(values):
    total = 0.0
    for v in values:
        total = total + v
    return total
