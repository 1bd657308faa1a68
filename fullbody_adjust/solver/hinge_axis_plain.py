"""body._hinge_axis on a few frames in plain floats: the elbow's and knee's default hinge axis, which Adjust Pose
computes again for every limb a click moved (its start pose is new). Each frame goes through the numpy path's
operations in its order (geometry_plain), so the axes are the same bits; a frame where a vector has no length or a
coordinate is not finite goes back to the numpy path, which raises or falls back as it does."""

import math

import numpy as np

from . import geometry_plain as g
from .errors import SolverInputError
from .geometry import TINY

# A slight start bend (up to HumanLimits.bent) keeps its own plane only within this cosine (10 degrees) of the given
# or body-frame axis: further off it is more likely noise on a nearly straight limb than the plane the limb bends
# in, and the hinge's twist range holds such a start anyway (45 degrees for knees, 80 for elbows).
SLIGHT_AGREES = math.cos(math.radians(10.0))


def hinge_axes(parent_seg, child_seg, bend_side, x_axis, bent_angle):
    """(F,3) hinge axes as body._hinge_axis computes them, or None to leave every frame to it."""
    rows = []
    xs = [None] * len(parent_seg) if x_axis is None else x_axis.tolist()
    for parent, child, side, x in zip(parent_seg.tolist(), child_seg.tolist(), bend_side.tolist(), xs):
        axis = _hinge_axis(parent, child, side, x, bent_angle)
        if axis is None:
            return None
        rows.append(axis)
    return np.array(rows, dtype=np.float64).reshape(parent_seg.shape)


def _hinge_axis(parent, child, side, x_axis, bent_angle):
    if not all(math.isfinite(c) for c in (*parent, *child, *side, *(x_axis or ()))):
        return None
    try:
        u = g.normalize(parent)
        heuristic = g.cross(u, g.normalize(side))
        if g.norm(heuristic) < 0.3:  # limb nearly along the bend side
            heuristic = g.any_perpendicular(u)
        axis = g.normalize(heuristic)
        if x_axis is not None:
            x = g.sub(x_axis, g.scaled(u, g.dot(x_axis, u)))
            ok = g.norm(x) > 1e-6
            x = g.normalize(x if ok else axis)
            if g.dot(x, axis) < 0.0:
                x = (-x[0], -x[1], -x[2])
            if ok:
                axis = x
        v = g.normalize(child)
        bend = g.cross(u, v)
        angle = float(np.arctan2(g.norm(bend), g.dot(u, v)))
        bend_axis = g.normalize(bend) if g.norm(bend) > TINY else g.normalize(axis)  # geometry.normalize's fallback
        agree = g.dot(bend_axis, axis)
        if angle > 1e-3 and abs(agree) >= SLIGHT_AGREES:
            axis = (-bend_axis[0], -bend_axis[1], -bend_axis[2]) if agree < 0.0 else bend_axis
        return g.normalize(bend_axis if angle > bent_angle else axis)
    except (ZeroDivisionError, SolverInputError):  # a vector of no length: the numpy path raises or falls back
        return None
