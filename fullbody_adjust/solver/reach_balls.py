"""Sub-base geometry (paper §5.2.1 eq. (1) and §4.2): the nearest point of an intersection of reach balls, on a
sphere within them, and the priority variants that decide where the balls do not intersect. Vectorised over
frames (F rows); one frame goes through reach_balls_plain.py (the same bits, without numpy's per-call cost)."""

from itertools import combinations

import numpy as np

from . import reach_balls_plain
from .reach_balls_plain import NEAR_CENTRE
from .geometry import any_set, cross, dot, norm, unit_or_perpendicular

_EYE = np.eye(3)
# Relative slack of "inside a ball" tests on computed points (their rounding is ~1e-16 relative).
_INSIDE_SLACK = 1e-12


def project_onto_balls(points, centres, radii):
    """Nearest point of each ball to each point: (F,3), (F,K,3), (F,K) -> (F,K,3). Inside points stay exactly."""
    d = points[:, None, :] - centres
    dist = norm(d)
    outside = dist > radii
    scale = np.where(outside, radii / np.where(outside, dist, 1.0), 1.0)
    return np.where(outside[..., None], centres + d * scale[..., None], points[:, None, :])


def _inside(x, centres, radii, active):
    """(F,) x lies in every active ball (F,K), within rounding slack."""
    dist = norm(x[:, None, :] - centres)
    ok = dist <= radii * (1.0 + _INSIDE_SLACK) + _INSIDE_SLACK
    return np.all(ok | ~active, axis=1)


def _circle_point(point, c1, r1, c2, r2):
    """Nearest point to `point` on the circle where spheres (c1,r1) and (c2,r2) meet: (F,3), valid (F,)."""
    axis = c2 - c1
    d = norm(axis)
    ok = d > 0.0
    u = np.where(ok[:, None], axis / np.where(ok, d, 1.0)[:, None], _EYE[0])  # concentric: no circle
    a = (d * d + r1 * r1 - r2 * r2) / (2.0 * np.where(ok, d, 1.0))
    h2 = r1 * r1 - a * a
    ok &= h2 >= 0.0
    h = np.sqrt(np.maximum(h2, 0.0))
    m = c1 + a[:, None] * u
    w = point - m
    # Twice: for a point near the axis, the in-plane part left by one pass is so small that that pass's rounding
    # tilts it out of the plane (2e-12 off the axis tilted it 1e-4 rad, off the sphere by 2e-5).
    w = w - dot(w, u)[:, None] * u
    w = w - dot(w, u)[:, None] * u
    wn = norm(w)
    # On the axis every circle point is equally near: take a deterministic one.
    w = unit_or_perpendicular(w, wn, wn > 1e-15, u)
    return m + h[:, None] * w, ok


def _sphere_triple(c1, r1, c2, r2, c3, r3):
    """The two points where three spheres meet (trilateration): (2,F,3), valid (F,)."""
    ex_v = c2 - c1
    d = norm(ex_v)
    ok = d > 0.0
    ex = np.where(ok[:, None], ex_v / np.where(ok, d, 1.0)[:, None], _EYE[0])
    v3 = c3 - c1
    i = dot(ex, v3)
    ey_v = v3 - i[:, None] * ex
    j = norm(ey_v)
    ok &= j > 1e-12 * np.maximum(d, 1e-300)
    ey = ey_v / np.where(ok, j, 1.0)[:, None]
    ez = cross(ex, ey)
    x = (r1 * r1 - r2 * r2 + d * d) / (2.0 * np.where(ok, d, 1.0))
    y = (r1 * r1 - r3 * r3 + i * i + j * j) / (2.0 * np.where(ok, j, 1.0)) - i / np.where(ok, j, 1.0) * x
    z2 = r1 * r1 - x * x - y * y
    ok &= z2 >= 0.0
    z = np.sqrt(np.maximum(z2, 0.0))
    base = c1 + x[:, None] * ex + y[:, None] * ey
    return np.stack([base + z[:, None] * ez, base - z[:, None] * ez]), ok


def nearest_in_balls(points, centres, radii, active):
    """Nearest point to `points` (F,3) of the intersection of the active balls (F,K,3)/(F,K)/(F,K) bool.

    Exact (closed form), by the active-set argument: the optimum is the point itself, its projection onto one
    sphere, the nearest point of a two-sphere circle, or a three-sphere point; the nearest feasible candidate
    wins. Returns (x (F,3), feasible (F,)): feasible False where the balls have no common point (x = points).
    A point already inside every ball is returned unchanged (bit-exact)."""
    if len(points) == 1:
        x, ok = reach_balls_plain.nearest_in_balls(points[0].tolist(), centres[0].tolist(), radii[0].tolist(),
                                                   active[0].tolist())
        return np.array([x], dtype=np.float64), np.array([ok])
    best = points.copy()
    feasible = _inside(points, centres, radii, active)
    best_d = np.where(feasible, 0.0, np.inf)
    todo = ~feasible
    if any_set(todo):
        # Only the rows outside some ball have candidates to weigh (a point inside all stays, at distance 0).
        rows = np.nonzero(todo)[0]
        best[rows], best_d[rows] = _nearest_candidate(points[rows], centres[rows], radii[rows], active[rows])
    feasible = np.isfinite(best_d)
    best = np.where(feasible[:, None], best, points)
    return best, feasible


def _nearest_candidate(points, centres, radii, active):
    """nearest_in_balls' candidates (projections, circle points, three-sphere points) for points outside
    some ball: the nearest valid one and its distance (inf where none is valid)."""
    k = radii.shape[1]
    cands = [project_onto_balls(points, centres, radii)]
    valid = [active]
    pairs = list(combinations(range(k), 2))
    if pairs:
        a, b = np.array(pairs).T
        pts, ok = _per_candidate(_circle_point, points[:, None], centres[:, a], radii[:, a], centres[:, b],
                                 radii[:, b])
        cands.append(pts)
        valid.append(ok & active[:, a] & active[:, b])
    triples = list(combinations(range(k), 3))
    if triples:
        a, b, c = np.array(triples).T
        pts, ok = _per_candidate(_sphere_triple, centres[:, a], radii[:, a], centres[:, b], radii[:, b],
                                 centres[:, c], radii[:, c])
        both = ok & active[:, a] & active[:, b] & active[:, c]
        cands.append(pts.reshape(len(points), 2 * len(triples), 3))  # each triple's two points in turn
        valid.append(np.repeat(both, 2, axis=1))
    return _nearest_valid(points, np.concatenate(cands, axis=1), np.concatenate(valid, axis=1), centres, radii,
                          active)


def _per_candidate(fn, *arrays):
    """Row-wise `fn` (points (F,3), ... -> (F,3) or (2,F,3), valid (F,)) on arrays with a candidate axis
    (F,C,...): the rows are stacked, so each candidate rounds exactly as a call of its own. Returns (F,C,3)
    or (F,C,2,3), and valid (F,C)."""
    f, c = np.broadcast_shapes(*(x.shape[:2] for x in arrays))
    pts, ok = fn(*(_stacked(x, f, c) for x in arrays))
    if pts.ndim == 3:  # two points per candidate
        return np.moveaxis(pts, 0, 1).reshape(f, c, 2, 3), ok.reshape(f, c)
    return pts.reshape(f, c, 3), ok.reshape(f, c)


def _stacked(x, f, c):
    """(F or 1, C or 1, ...) -> (F*C, ...), rows repeated where x has one."""
    if x.shape[:2] != (f, c):
        x = np.repeat(np.repeat(x, f // max(x.shape[0], 1), axis=0), c // max(x.shape[1], 1), axis=1)
    return x.reshape((f * c,) + x.shape[2:])


def _nearest_valid(points, cands, valid, centres, radii, active):
    """The candidate (F,C,3) nearest to `points` (F,3) among the valid ones (F,C) that lie in every active
    ball, the first one on a tie; and its distance (inf and `points` where none is valid)."""
    f, c = cands.shape[:2]
    inside = _inside(cands.reshape(f * c, 3), np.repeat(centres, c, axis=0), np.repeat(radii, c, axis=0),
                     np.repeat(active, c, axis=0)).reshape(f, c)
    dist = norm(cands - points[:, None])
    key = np.where(valid & inside & ~np.isnan(dist), dist, np.inf)
    pick = np.argmin(key, axis=1)
    rows = np.arange(f)
    best_d = key[rows, pick]
    best = np.where(np.isfinite(best_d)[:, None], cands[rows, pick], points)
    return best, best_d


def nearest_on_sphere_in_balls(points, centre, radius, centres, radii, active):
    """Nearest point to `points` (F,3) on the sphere (centre (F,3), radius (F,)) that lies in every active ball
    (F,K,3)/(F,K)/(F,K). Candidates as in nearest_in_balls with the sphere always active: the radial
    projection, the sphere's circle with each ball's boundary, the two points it shares with two boundaries.
    Returns (x, found (F,))."""
    if len(points) == 1:
        x, ok = reach_balls_plain.nearest_on_sphere_in_balls(points[0].tolist(), centre[0].tolist(),
                                                             float(radius[0]), centres[0].tolist(),
                                                             radii[0].tolist(), active[0].tolist())
        return np.array([x], dtype=np.float64), np.array([ok])
    k = radii.shape[1]
    d = points - centre
    dn = norm(d)
    away = dn > NEAR_CENTRE
    radial = centre + d * (radius / np.where(away, dn, 1.0))[:, None]
    radial = np.where(away[:, None], radial, centre + radius[:, None] * _EYE[0])  # any point will do
    cands = [radial[:, None]]
    valid = [np.ones((len(points), 1), dtype=bool)]
    if k:
        pts, ok = _per_candidate(_circle_point, points[:, None], centre[:, None], radius[:, None], centres, radii)
        cands.append(pts)
        valid.append(ok & active)
    pairs = list(combinations(range(k), 2))
    if pairs:
        a, b = np.array(pairs).T
        pts, ok = _per_candidate(_sphere_triple, centre[:, None], radius[:, None], centres[:, a], radii[:, a],
                                 centres[:, b], radii[:, b])
        cands.append(pts.reshape(len(points), 2 * len(pairs), 3))
        valid.append(np.repeat(ok & active[:, a] & active[:, b], 2, axis=1))
    best, best_d = _nearest_valid(points, np.concatenate(cands, axis=1), np.concatenate(valid, axis=1), centres,
                                  radii, active)
    found = np.isfinite(best_d)
    return best, found


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
    if len(points) == 1 and variant == "priority" and not any_set(np.isnan(prio)):
        x, ok = reach_balls_plain.sub_base_point_priority(points[0].tolist(), centres[0].tolist(), radii[0].tolist(),
                                                          active[0].tolist(), prio.tolist())
        return np.array([x], dtype=np.float64), np.array([ok])
    x, feasible = nearest_in_balls(points, centres, radii, active)
    todo = ~feasible & np.any(active, axis=1)
    if not any_set(todo):
        return x, feasible
    rows = np.nonzero(todo)[0]
    p, c, r, act = points[rows], centres[rows], radii[rows], active[rows]
    if variant in ("weighted", "fabrik"):
        proposals = project_onto_balls(p, c, r)
        w = np.where(act, prio[None, :] if variant == "weighted" else 1.0, 0.0)
        w = np.where(w.sum(axis=1, keepdims=True) > 0.0, w, act.astype(np.float64))  # all-zero priorities
        y = np.einsum("fk,fki->fi", w, proposals) / w.sum(axis=1)[:, None]
    else:
        order = np.argsort(-prio, kind="stable")
        kept = np.zeros_like(act)
        for k in order:
            trial = kept.copy()
            trial[:, k] |= act[:, k]
            if trial.sum(axis=1).max() <= 1:
                kept = trial  # one ball (or none) always has a point
                continue
            if np.array_equal(trial, act):
                continue  # all of them: these rows are those whose balls have no common point (above)
            _, ok = nearest_in_balls(p, c, r, trial)
            kept = np.where(ok[:, None], trial, kept)
        y = p.copy()
        for k in order[::-1]:
            dropped = act[:, k] & ~kept[:, k]
            y = np.where(dropped[:, None], project_onto_balls(y, c[:, k:k + 1], r[:, k:k + 1])[:, 0], y)
        y, _ = nearest_in_balls(y, c, r, kept)
    x = x.copy()
    x[rows] = y
    return x, feasible

