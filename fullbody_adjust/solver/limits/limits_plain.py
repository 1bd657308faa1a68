"""limits/joint_limits.py's joint limits on one direction in plain Python floats (the chain solver limits one or two chains'
joints at a time when it solves one frame, and the segment rotations written out turn by the hinge twist): the
numpy path's operations in its order, the trigonometry, hypot and remainder numpy's own routines on one value
(maths/geometry_plain.py), so each gives the numpy path's bits (tests/solver/test_limits_plain.py). Vectors are
3-tuples."""

import math

import numpy as np

from ..maths import geometry_plain as g
from .joint_limits import _DEGENERATE, CONE, hinge_frame


def limit(limits, i, parent, v, fallback, axis, reverse=False):
    """Joint i's limit (JointLimits `limits`) on unit direction v of its segment, as chain_model.ChainModel.
    _limit applies it (reverse: as _limit_reverse does, `parent` then the child's direction and the hinge range
    mirrored); `axis` the hinge axis carried to where it applies. Returns (direction, binding)."""
    if limits.kind[i] == CONE:
        return apply_cone(parent, v, float(limits.cone_angle[i]), fallback)
    lo, hi = float(limits.hinge_min[i]), float(limits.hinge_max[i])
    if reverse:
        lo, hi = -hi, -lo
    twist = None if limits.hinge_twist is None else float(limits.hinge_twist[i])
    return apply_hinge(parent, v, axis, lo, hi, fallback, twist)


def _cone(parent, v, angle):
    c = g.dot(parent, v)
    w = g.sub(v, g.scaled(parent, c))
    wn = g.norm(w)
    return float(np.arctan2(wn, c)) > angle, w, wn


def apply_cone(parent, v, angle, fallback):
    """limits.apply_cone for one direction: (limited direction, binding)."""
    over, w, wn = _cone(parent, v, angle)
    if not over:
        return v, False
    if not wn > _DEGENERATE:
        w = g.sub(fallback, g.scaled(parent, g.dot(fallback, parent)))
        if not g.norm(w) > _DEGENERATE:
            w = g.any_perpendicular(parent)
    e = g.divided_by_norm(g.sub(w, g.scaled(parent, g.dot(w, parent))))
    return g.add(g.scaled(parent, float(np.cos(angle))), g.scaled(e, float(np.sin(angle)))), True


def apply_hinge(parent, v, axis, lo, hi, fallback, twist):
    """limits.apply_hinge for one direction: (limited direction, binding)."""
    a, side = hinge_frame(parent, axis)
    if twist is not None and twist > 0.0:
        return _apply_twisted_hinge(parent, v, a, side, lo, hi, fallback, twist)
    x, y = g.dot(v, parent), g.dot(v, side)
    if not _hypot(x, y) > _DEGENERATE:
        x, y = g.dot(fallback, parent), g.dot(fallback, side)
        if not _hypot(x, y) > _DEGENERATE:
            x, y = 1.0, 0.0
    theta = _clamp_angle(float(np.arctan2(y, x)), lo, hi)
    limited = g.add(g.scaled(parent, float(np.cos(theta))), g.scaled(side, float(np.sin(theta))))
    return limited, g.norm(g.sub(limited, v)) > 1e-12


def _apply_twisted_hinge(parent, v, a, side, lo, hi, fallback, twist):
    x, y, z = g.dot(v, parent), g.dot(v, side), g.dot(v, a)
    r, phi = _hypot(y, z), float(np.arctan2(z, y))
    if not _hypot(x, r * float(np.cos(phi - _clip(phi, twist)))) > _DEGENERATE:
        x, y2, z2 = g.dot(fallback, parent), g.dot(fallback, side), g.dot(fallback, a)
        r, phi = _hypot(y2, z2), float(np.arctan2(z2, y2))
        if not _hypot(x, r * float(np.cos(phi - _clip(phi, twist)))) > _DEGENERATE:
            x, r, phi = 1.0, 0.0, 0.0
    best = best_dot = None
    for wanted in (phi, phi - math.pi if phi > 0.0 else phi + math.pi):
        tau = _clip(wanted, twist)
        theta = _clamp_angle(float(np.arctan2(r * float(np.cos(phi - tau)), x)), lo, hi)
        sin_t = float(np.sin(theta))
        plane = g.add(g.scaled(side, float(np.cos(tau))), g.scaled(a, float(np.sin(tau))))
        cand = g.add(g.scaled(parent, float(np.cos(theta))), g.scaled(plane, sin_t))
        c = g.dot(cand, v)
        if best is None:
            best, best_dot = cand, c
        elif c > best_dot:
            best = cand
    return best, g.norm(g.sub(best, v)) > 1e-12


def _clamp_angle(theta, lo, hi):
    if lo <= theta <= hi:
        return theta
    to_lo = abs(float(np.remainder(theta - lo + math.pi, 2 * math.pi)) - math.pi)
    to_hi = abs(float(np.remainder(theta - hi + math.pi, 2 * math.pi)) - math.pi)
    return lo if to_lo <= to_hi else hi


def _clip(angle, twist):
    return min(max(angle, -twist), twist)


def _hypot(x, y):
    return float(np.hypot(x, y))
